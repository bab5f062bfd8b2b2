"""Training-loader throughput: decoded shard samples/s versus model-ready tensors/s, on generated CARLA routes.

.venv/bin/python benchmarks/loader.py --routes 6 --frames 16 --workers 0 2

The baseline is reading and decoding the same shards with ``read_samples`` in the same process; the ratio shows what
the transforms (JPEG decode + resize, LiDAR raster, CenterNet and BEV targets at paper sizes) cost on top.
"""

import argparse
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

from lead_s2r.convert import convert
from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.models.config import tfv6_config
from lead_s2r.registry import get_adapter
from lead_s2r.shards import read_samples
from lead_s2r.synthetic.carla_lead import generate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--routes", type=int, default=6)
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--workers", type=int, nargs="+", default=[0, 2])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        raw, data = Path(tmp) / "raw", Path(tmp) / "data"
        generate(raw, count=args.routes, frames=args.frames)
        convert(get_adapter("carla_lead"), raw, data)
        started = time.perf_counter()
        count = sum(1 for _ in read_samples(data))
        baseline = count / (time.perf_counter() - started)
        print(f"read_samples (decode every field, 1 process): {baseline:.1f} samples/s over {count} samples")
        for workers in args.workers:
            dm = DriveDataModule(
                train={"carla": SourceSpec([str(data)])},
                schedule=MixingSchedule.constant({"carla": 1.0}, args.batch_size),
                steps_per_epoch=args.steps,
                num_workers=workers,
                config=tfv6_config(),  # paper sizes: 1152x384 mosaic, 384x320 BEV
            )
            dm.trainer = SimpleNamespace(current_epoch=0, world_size=1)
            loader = dm.train_dataloader()["carla"]
            started = time.perf_counter()
            samples = sum(len(batch["__key__"]) for batch in loader)
            rate = samples / (time.perf_counter() - started)
            print(
                f"DriveDataModule train loader, workers={workers}: {rate:.1f} samples/s "
                f"({rate / baseline:.2f}x read_samples; start-up included)"
            )


if __name__ == "__main__":
    main()
