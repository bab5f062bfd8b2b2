"""Training-loader throughput at TFv6 paper sizes, side by side in one process, on generated LEAD routes.

.venv/bin/python benchmarks/loader.py --routes 6 --frames 16 --steps 40 --rounds 3

Two kinds of generated frames (``--kinds``): light ones (five actors, about 700 LiDAR points: the tests' frames) and
realistic ones (``generate(realistic=True)``: about 60 actors, about 60,000 LiDAR + radar points in the LAZ, metas
with every target-point planner LEAD saves). Per kind, each converted with our adapter:

- plain decoding: ``read_samples`` over the converted shards, every field decoded (JPEG bytes stay bytes): the
  floor any shard loader pays; shown also with the JPEGs decoded to pixels, for reference;
- ours: ``DriveDataModule``'s training loader (shard resampling, shuffle buffer, decoding the fields the transform
  reads, ``SourceTransform`` at paper sizes: 1152x384 mosaic, 384x320 LiDAR BEV, CenterNet at stride 4, BEV labels,
  depth and semantics; collation into batches); the shards hold the LiDAR as points, so ours rasterises them too.
  One epoch's stream serves every round, as in training: the shuffle buffer fills once (timed and printed apart),
  not once per 40-batch pass, which would read 256 samples more than it yields each time;
- LEAD-style: ``lead_style.LeadStyleFrames`` over the raw route folders of the same frames, shuffled by a torch
  ``DataLoader`` with its default collation: LEAD's per-frame steps and LEAD's tensor contract (see that module),
  building both rigs per item as LEAD does without a cache, and (for a conservative bound) only the rig it returns.
  Its camera and perspective labels are checked against ours on one frame.

"After the first batch" leaves out each pass's first batch. Torch runs one intra-op thread (``--threads``), as in a
dataloader worker: with the default two on this shared 2-core machine, collation's ``torch.stack`` spun and took 4x
longer.

The loaders run in turn within each round (interleaved), so a busy machine slows all alike; the ratios are per round
and the summary gives their median. CPU time is this process's (user + system).
"""

import argparse
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import torch
from lead_style import LeadStyleFrames
from torch.utils.data import DataLoader

from lead_s2r.convert import convert
from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.models.input_spec import InputSpec, input_spec
from lead_s2r.models.inputs import on_image_grid
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.registry import get_adapter
from lead_s2r.schema import make_key
from lead_s2r.shards import read_samples
from lead_s2r.synthetic.carla_lead import generate

PLAIN, PIXELS, OURS, OURS_DEVICE, LEAD_BOTH, LEAD_ONE = (
    "plain decoding (read_samples, every field)",
    "plain decoding + JPEG to pixels",
    "ours (DriveDataModule)",
    "ours, JPEG and LiDAR left for the GPU (inputs_on_device)",
    "LEAD-style per-file, both rigs (LEAD uncached)",
    "LEAD-style per-file, one rig",
)


@dataclass
class Timing:
    """One loader's pass: samples, wall and CPU seconds; ``steady_*`` leave out its first batch."""

    samples: int
    wall: float
    cpu: float
    steady_samples: int
    steady_wall: float

    @property
    def rate(self) -> float:
        return self.samples / self.wall

    @property
    def steady_rate(self) -> float:
        return self.steady_samples / self.steady_wall


def timed(batches: Iterator[int]) -> Timing:
    """Time a loader given as an iterator over its batch sizes."""
    wall, cpu = time.perf_counter(), time.process_time()
    first = next(batches)
    after_first = time.perf_counter()
    rest = sum(batches)
    end = time.perf_counter()
    return Timing(first + rest, end - wall, time.process_time() - cpu, rest, end - after_first)


def check_agreement(data: Path, lead: LeadStyleFrames, transform: SourceTransform) -> None:
    """The LEAD-style loader reads the same frames as ours: equal RGB and semantics, depth equal to float32 rounding
    once ours is on the image grid (the LiDAR raster and BEV labels differ in frame and orientation by design)."""
    keys = {make_key(*lead.key(i).rsplit("/", 1)): i for i in range(len(lead))}  # the adapter's keys, normal rig
    sample = next(sample for sample in read_samples(data, transform.fields) if sample["__key__"] in keys)
    ours, index = transform(sample), keys[sample["__key__"]]
    theirs = lead[index]
    assert np.array_equal(ours["rgb"].numpy(), theirs["rgb"]), "rgb"
    assert np.array_equal(ours["semantic"].long().numpy(), theirs["semantic"]), "semantic"
    depth = on_image_grid(ours["depth"][None], tuple(ours["rgb"].shape[-2:]))[0].numpy()
    np.testing.assert_allclose(depth, theirs["depth"], rtol=1e-5, atol=1e-4, err_msg="depth")


def loaders(
    kind: str, tmp: Path, args: argparse.Namespace, config: InputSpec
) -> dict[str, Callable[[], Iterator[int]]]:
    """The loaders over one kind of generated frames, as callables that start a pass and yield batch sizes."""
    raw, data = tmp / kind / "raw", tmp / kind / "data"
    generate(raw, count=args.routes, frames=args.frames, realistic=kind == "realistic")
    convert(get_adapter("carla_lead"), raw, data)
    check_agreement(data, LeadStyleFrames(raw), SourceTransform("carla", config))
    streams = {to_device: training_stream(kind, data, args, config, to_device) for to_device in (False, True)}
    lead = {
        views: DataLoader(LeadStyleFrames(raw, views), args.batch_size, shuffle=True, num_workers=args.workers)
        for views in (1, 2)
    }

    def lead_run(views: int) -> Iterator[int]:
        return (len(batch["key"]) for _, batch in zip(range(args.steps), _forever(lead[views]), strict=False))

    return {
        PLAIN: lambda: (1 for _ in read_samples(data)),
        PIXELS: lambda: (_decode_jpegs(sample) for sample in read_samples(data)),
        OURS: lambda: (len(next(streams[False])["__key__"]) for _ in range(args.steps)),
        OURS_DEVICE: lambda: (len(next(streams[True])["__key__"]) for _ in range(args.steps)),
        LEAD_BOTH: lambda: lead_run(2),
        LEAD_ONE: lambda: lead_run(1),
    }


def training_stream(
    kind: str, data: Path, args: argparse.Namespace, config: InputSpec, inputs_on_device: bool
) -> Iterator[dict[str, Any]]:
    """One epoch's stream of our training loader, as in training: every round goes on with it."""
    dm = DriveDataModule(
        train={"carla": SourceSpec([str(data)])},
        schedule=MixingSchedule.constant({"carla": 1.0}, args.batch_size),
        steps_per_epoch=args.steps * args.rounds + 1,
        num_workers=args.workers,
        inputs=config,
        inputs_on_device=inputs_on_device,
    )
    dm.trainer = SimpleNamespace(current_epoch=0, world_size=1)
    wall, cpu = time.perf_counter(), time.process_time()
    stream = iter(dm.train_dataloader()["carla"])
    first = next(stream)
    print(
        f"{kind}: ours (inputs_on_device={inputs_on_device}), the shuffle buffer's fill and the first batch (once per "
        f"epoch and worker): {time.perf_counter() - wall:.2f} s wall, {time.process_time() - cpu:.2f} s CPU for "
        f"{len(first['__key__'])}"
    )
    return stream


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--routes", type=int, default=6)
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--steps", type=int, default=40, help="batches per round for ours and the LEAD-style loader")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=0, help="loader workers for ours and the LEAD-style loader")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (collation)")
    parser.add_argument("--kinds", nargs="+", default=["light", "realistic"], choices=["light", "realistic"])
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    config = input_spec(LeadConfig(use_planning_decoder=True))  # LEAD's TFv6 at paper sizes
    print(f"load average at start: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    with tempfile.TemporaryDirectory() as tmp:
        runs = {kind: loaders(kind, Path(tmp), args, config) for kind in args.kinds}
        timings: dict[tuple[str, str], list[Timing]] = {(k, n): [] for k, per in runs.items() for n in per}
        for round_index in range(args.rounds):
            for kind, per_kind in runs.items():
                for name, run in per_kind.items():
                    timing = timed(run())
                    timings[kind, name].append(timing)
                    print(
                        f"round {round_index}, {kind}: {name}: {timing.samples} samples, {timing.rate:.1f} samples/s "
                        f"({timing.steady_rate:.1f} after the first batch), "
                        f"{timing.cpu / timing.samples * 1e3:.2f} ms CPU/sample"
                    )
        print(f"load average at end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
        print(f"median over {args.rounds} rounds (ratios: median of the per-round ratios):")
        for kind in runs:
            for name in runs[kind]:
                runs_of = timings[kind, name]
                rate = statistics.median(t.rate for t in runs_of)
                steady = statistics.median(t.steady_rate for t in runs_of)
                cpu = statistics.median(t.cpu / t.samples * 1e3 for t in runs_of)
                print(f"  {kind}: {name}: {rate:.1f} samples/s ({steady:.1f} after the first batch), {cpu:.2f} ms CPU")
            for name in (OURS, OURS_DEVICE):
                ours = timings[kind, name]
                for label, attribute in (("every batch", "rate"), ("after the first batch", "steady_rate")):
                    over_plain = _median_ratio(ours, timings[kind, PLAIN], attribute, "rate")
                    both = _median_ratio(ours, timings[kind, LEAD_BOTH], attribute, attribute)
                    one = _median_ratio(ours, timings[kind, LEAD_ONE], attribute, attribute)
                    print(
                        f"  {kind}, {name}, {label}: {over_plain:.2f}x plain decoding, {both:.2f}x LEAD-style "
                        f"(both rigs), {one:.2f}x LEAD-style (one rig)"
                    )


def _decode_jpegs(sample: dict[str, Any]) -> int:
    for name, value in sample.items():
        if name.startswith("cam_"):
            cv2.imdecode(np.frombuffer(value, np.uint8), cv2.IMREAD_COLOR)
    return 1


def _median_ratio(a: list[Timing], b: list[Timing], attribute_a: str, attribute_b: str) -> float:
    return statistics.median(getattr(x, attribute_a) / getattr(y, attribute_b) for x, y in zip(a, b, strict=True))


def _forever(loader: DataLoader):
    while True:
        yield from loader


if __name__ == "__main__":
    main()
