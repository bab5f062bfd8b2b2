"""Training-loader throughput at TFv6 paper sizes, three loaders side by side in one process, on generated routes.

.venv/bin/python benchmarks/loader.py --routes 6 --frames 16 --steps 40 --rounds 3

- plain decoding: ``read_samples`` over the converted shards, every field decoded (JPEG bytes stay bytes): the
  floor any shard loader pays; shown also with the JPEGs decoded to pixels, for reference;
- ours: ``DriveDataModule``'s training loader (shard resampling, shuffle buffer, decoding the fields the transform
  reads, ``SourceTransform`` at paper sizes: 1152x384 mosaic, 384x320 LiDAR BEV, CenterNet at stride 4, BEV labels,
  depth and semantics; collation into batches);
- LEAD-style: a map-style dataset over the raw LEAD route folders of the same frames, shuffled by a torch
  ``DataLoader``; each item opens its frame's files as LEAD's loader does when it builds a sample (LZMA pickles of
  the meta and the boxes, the LAZ point cloud, the JPEG, semantic/depth/hdmap PNGs, the radar npz), turns them into a
  schema sample with the adapter's own code and applies the same transform, so the tensors are the same (checked on
  one frame). LEAD's optional persistent cache of compressed samples is not modelled.

Torch runs one intra-op thread (``--threads``), as in a dataloader worker: with the default two on this shared
2-core machine, collation's ``torch.stack`` spun and took 4x longer. "After the first batch" leaves out the shuffle
buffer's fill, which a long epoch amortises.

The loaders run in turn within each round (interleaved), so a busy machine slows all three alike; the ratios are
per round and the summary gives their median. CPU time is this process's (user + system).
"""

import argparse
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
from torch.utils.data import DataLoader, Dataset

from lead_s2r.convert import convert
from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.data.transforms import SourceTransform, collate
from lead_s2r.models.config import tfv6_config
from lead_s2r.registry import LogRef, get_adapter
from lead_s2r.shards import read_samples
from lead_s2r.synthetic.carla_lead import generate
from lead_s2r_adapters.carla_lead import CarlaLeadAdapter
from lead_s2r_adapters.carla_lead_io import read_laz, read_pickle


class LeadFrames(Dataset):
    """One item per frame of the raw route folders under ``src``: read from its files, then transformed."""

    def __init__(self, src: Path, transform: SourceTransform) -> None:
        self.adapter = get_adapter("carla_lead")
        assert isinstance(self.adapter, CarlaLeadAdapter)
        self.transform = transform
        self.items: list[tuple[LogRef, str]] = [
            (log, path.stem)
            for log in self.adapter.list_logs(src)
            for path in sorted((Path(log.path) / "bboxes").glob("*.pkl"))
        ]

    def __len__(self) -> int:
        return len(self.items)

    def sample(self, index: int) -> dict[str, Any]:
        """The schema sample of one frame, built from its own files (what LEAD's ``__getitem__`` reads)."""
        log, name = self.items[index]
        folder = Path(log.path)
        meta_path = folder / "metas" / f"{name}.pkl"
        meta = read_pickle(meta_path)
        others = [box for box in read_pickle(folder / "bboxes" / f"{name}.pkl") if box.get("class") != "ego_car"]
        lidar = read_laz(folder / "lidar" / f"{name}.laz")
        return self.adapter._sample(log, folder, name, meta, meta_path, others, lidar, "normal")

    def __getitem__(self, index: int) -> dict[str, Any]:
        return self.transform(self.sample(index))


@dataclass
class Timing:
    """One loader's pass: samples, wall and CPU seconds; ``steady_*`` leave out the first batch (buffer fill)."""

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


def check_same_tensors(data: Path, lead: LeadFrames) -> None:
    """The LEAD-style loader and ours give equal tensors for one frame (else the comparison is meaningless)."""
    transform = lead.transform
    ours = transform(next(iter(read_samples(data, transform.fields))))
    index = next(i for i, (log, name) in enumerate(lead.items) if ours["__key__"].endswith(name))
    theirs = lead[index]
    assert theirs["__key__"] == ours["__key__"], (theirs["__key__"], ours["__key__"])
    for name, value in ours.items():
        if isinstance(value, torch.Tensor) and not torch.equal(value, theirs[name]):
            raise AssertionError(f"LEAD-style loader differs from ours in {name!r}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--routes", type=int, default=6)
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--steps", type=int, default=40, help="batches per round for ours and the LEAD-style loader")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=0, help="loader workers for ours and the LEAD-style loader")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (collation)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    config = tfv6_config()  # paper sizes
    with tempfile.TemporaryDirectory() as tmp:
        raw, data = Path(tmp) / "raw", Path(tmp) / "data"
        generate(raw, count=args.routes, frames=args.frames)
        convert(get_adapter("carla_lead"), raw, data)
        lead = LeadFrames(raw, SourceTransform("carla", config))
        check_same_tensors(data, lead)
        dm = DriveDataModule(
            train={"carla": SourceSpec([str(data)])},
            schedule=MixingSchedule.constant({"carla": 1.0}, args.batch_size),
            steps_per_epoch=args.steps,
            num_workers=args.workers,
            config=config,
        )
        dm.trainer = SimpleNamespace(current_epoch=0, world_size=1)
        lead_loader = DataLoader(
            lead, batch_size=args.batch_size, shuffle=True, num_workers=args.workers, collate_fn=collate
        )
        runs: dict[str, Callable[[], Iterator[int]]] = {
            "plain decoding (read_samples, every field)": lambda: (1 for _ in read_samples(data)),
            "plain decoding + JPEG to pixels": lambda: (_decode_jpegs(sample) for sample in read_samples(data)),
            f"ours (DriveDataModule, workers={args.workers})": lambda: (
                len(batch["__key__"]) for batch in dm.train_dataloader()["carla"]
            ),
            f"LEAD-style per-file (workers={args.workers})": lambda: (
                len(batch["__key__"]) for _, batch in zip(range(args.steps), _forever(lead_loader), strict=False)
            ),
        }
        timings: dict[str, list[Timing]] = {name: [] for name in runs}
        plain, _, ours, per_file = list(runs)
        for round_index in range(args.rounds):
            for name, run in runs.items():
                timing = timed(run())
                timings[name].append(timing)
                print(
                    f"round {round_index}: {name}: {timing.samples} samples, {timing.rate:.1f} samples/s "
                    f"({timing.steady_rate:.1f} after the first batch), {timing.cpu / timing.samples * 1e3:.2f} ms "
                    "CPU/sample"
                )
        print(f"median over {args.rounds} rounds (ratios: median of the per-round ratios):")
        for name, runs_of in timings.items():
            rate = statistics.median(t.rate for t in runs_of)
            steady = statistics.median(t.steady_rate for t in runs_of)
            cpu = statistics.median(t.cpu / t.samples * 1e3 for t in runs_of)
            print(f"  {name}: {rate:.1f} samples/s ({steady:.1f} after the first batch), {cpu:.2f} ms CPU/sample")
        for label, attribute in (("start-up included", "rate"), ("after the first batch", "steady_rate")):
            over_plain = _median_ratio(timings[ours], timings[plain], attribute, "rate")
            over_lead = _median_ratio(timings[ours], timings[per_file], attribute, attribute)
            print(f"  ours, {label}: {over_plain:.2f}x plain decoding, {over_lead:.2f}x LEAD-style")


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
