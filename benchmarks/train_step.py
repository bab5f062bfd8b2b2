"""Forward+backward+AdamW step throughput and peak memory of TFv6 / LTFv6 at the paper's input sizes.

TFv6: CARLA leaderboard rig (3-camera 1152x384 mosaic, LiDAR BEV 384x320, radar), all CARLA losses.
LTFv6: NAVSIM rig (4-camera 1920x270 mosaic, coordinate-grid BEV 256x256), NAVSIM planning + perception losses.

    python benchmarks/train_step.py --device cpu --batch-size 1 --steps 2
    python benchmarks/train_step.py --device cuda --batch-size 16 --precision bf16 --channels-last --compile
"""

import argparse
import resource
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))  # random model inputs live with the tests
from batches import random_batch

from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_driver import ltfv6_navsim, tfv6
from lead_s2r.training.module import DrivingModule

MODELS = {"tfv6": (tfv6, "carla"), "ltfv6": (ltfv6_navsim, "navsim")}


def to_device(batch: dict, device: torch.device, channels_last: bool) -> dict:
    out = {}
    for key, value in batch.items():
        if isinstance(value, torch.Tensor):
            value = value.to(device, non_blocking=True)
            if channels_last and value.dim() == 4:
                value = value.contiguous(memory_format=torch.channels_last)
        out[key] = value
    return out


def peak_memory_gib(device: torch.device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**30
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # Linux reports KiB: process peak RSS


def bench(name: str, args: argparse.Namespace) -> str:
    make, source = MODELS[name]
    model = make(image_architecture=args.architecture, lidar_architecture=args.architecture)
    device = torch.device(args.device)
    if args.channels_last:
        model = model.to(memory_format=torch.channels_last)
    module = DrivingModule(model, supervise={source: ["planning", "perception"]}, compile=args.compile).to(device)
    optimizer = module.configure_optimizers()
    batch = {source: to_device(random_batch(model, args.batch_size, source), device, args.channels_last)}
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)

    def train_step() -> None:
        optimizer.zero_grad(set_to_none=True)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=args.precision == "bf16"):
            total, _ = module.compute_losses(batch)
        total.backward()
        optimizer.step()

    def timed(steps: int) -> float:
        start = time.perf_counter()
        for _ in range(steps):
            train_step()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return time.perf_counter() - start

    warm = timed(args.warmup)
    elapsed = timed(args.steps)
    rate = args.batch_size * args.steps / elapsed
    height, width = input_spec(model.config).image_size
    return (
        f"| {name} | {args.architecture} | {sum(p.numel() for p in model.parameters()) / 1e6:.1f}M | {width}x{height} "
        f"| {args.device} | {args.precision} | {args.channels_last} | {args.compile} | {args.batch_size} "
        f"| {rate:.2f} | {elapsed / args.steps * 1000:.0f} | {peak_memory_gib(device):.2f} | {warm:.1f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", default=sorted(MODELS), choices=sorted(MODELS))
    parser.add_argument("--architecture", default="resnet34")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--batch-size", type=int, default=1)
    parser.add_argument("--steps", type=int, default=2)
    parser.add_argument("--warmup", type=int, default=1)
    parser.add_argument("--precision", choices=("32", "bf16"), default="32")
    parser.add_argument("--channels-last", action="store_true")
    parser.add_argument("--compile", action="store_true")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch default)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.device == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
        torch.backends.cudnn.benchmark = True
    print(
        "| model | encoders | params | image | device | precision | channels_last | compile | batch "
        "| samples/s | ms/step | peak mem GiB | warm-up s |"
    )
    print("|" + "---|" * 13)
    for name in args.models:
        print(bench(name, args), flush=True)


if __name__ == "__main__":
    main()
