"""Training-loader throughput at paper sizes against plain shard decoding, side by side in one process.

.venv/bin/python benchmarks/loader.py --kinds realistic navsim wod --steps 40 --rounds 3 --two-workers

One core: every loader but the 2-worker one runs in this one process (no dataloader workers, one torch thread).

Prints, per kind of generated data, the median over ``--rounds`` rounds (after one warm-up round) of: plain shard
decoding samples/s (``read_samples`` over the converted shards, every field decoded, JPEG bytes left as bytes: the
floor any shard loader pays); our training loader's samples/s and CPU ms per sample; their ratio, measured in the
same round (a busy machine slows both alike), with the spread of that ratio over the rounds; the same by CPU
time and by each loader's fastest slice of the round (``--slices`` below). Kinds:

- ``light`` / ``realistic``: generated LEAD CARLA routes (light: five actors, about 700 LiDAR points, the tests'
  frames; realistic: about 60 actors, about 60,000 LiDAR + radar points, metas with every target-point planner),
  for LEAD's CARLA TFv6 at ``LeadConfig()`` defaults (1152x384 mosaic, 384x320 LiDAR BEV, radar, CenterNet at stride
  4, BEV labels, depth and semantics). Ours twice: everything built in the loader (``inputs_on_device=False``, a
  CPU-only run) and the JPEG and LiDAR points left for the GPU (``inputs_on_device=True``, a run on a GPU);
- ``navsim``: generated NAVSIM logs (``lead-s2r synth navsim``) for the NAVSIM LTFv6 recipe's inputs
  (recipes/navsim/ltfv6.yaml: four cameras at NAVSIM's vertical field of view into 1920x270, BEV semantics, boxes);
- ``wod``: generated WOD-E2E segments for the WOD-E2E LTFv6 recipe's inputs (recipes/wod/ltfv6.yaml: three front
  cameras into 972x360), ours twice: everything in the loader and the camera JPEGs left for the GPU (decoded and laid
  out there, ``lead_s2r.data.device_inputs``).

Ours is ``DriveDataModule``'s training loader (shard resampling, shuffle buffer, decoding the fields the transform
reads, ``SourceTransform``, collation into batches of ``--batch-size``); one epoch's stream serves every round, as in
training: the shuffle buffer fills once (timed and printed apart). ``--two-workers`` adds ours with 2 dataloader
workers (its ratio is to plain decoding in one process). ``--lead-style`` adds, for the CARLA kinds,
``lead_style.LeadStyleFrames`` over the raw route folders (LEAD's per-frame steps and tensor contract, both rigs as
LEAD builds them uncached, and one rig), checked against ours on one frame.

Both sides of a ratio run over as many samples (plain decoding cycles over the shards until it has read
``--steps`` x ``--batch-size``), and within a round they take turns: each loader's pass is cut into ``--slices``
slices run alternately (plain decoding, ours, ours for the GPU, then back), so a change in the shared machine's
load weighs on both sides of a ratio alike (docs/benchmarks.md, "Fifth round"). The process's Python heap is frozen
before the first round (``gc.freeze``, as the loader's workers do) and collected before every slice: otherwise the
occasional full collection over the half a million objects torch, Lightning and the generated data leave (0.2 s of
CPU) lands in whichever pass is
running (docs/benchmarks.md, "Third round").

Torch runs one intra-op thread (``--threads``), as a dataloader worker does. CPU time is this process's (user +
system); with workers it is the workers' too (their CPU is not this process's: the row says so).
"""

import argparse
import gc
import itertools
import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
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
from lead_s2r.synthetic import navsim, wod_e2e
from lead_s2r.synthetic.carla_lead import generate

PLAIN, PIXELS, OURS, OURS_DEVICE, OURS_TWO, LEAD_BOTH, LEAD_ONE = (
    "plain decoding (read_samples, every field)",
    "plain decoding + JPEG to pixels",
    "ours (DriveDataModule), everything in the loader",
    "ours, camera JPEGs and LiDAR points left for the GPU (inputs_on_device)",
    "ours, 2 workers (samples/s of both; CPU: the main process only)",
    "LEAD-style per-file, both rigs (LEAD uncached)",
    "LEAD-style per-file, one rig",
)

#: LEAD config switches of each kind's model (the recipes' ``model.config``), its source and its cameras.
KINDS: dict[str, tuple[str, dict[str, Any], list[str]]] = {
    "light": ("carla", {"use_planning_decoder": True}, ["carla_mosaic"]),
    "realistic": ("carla", {"use_planning_decoder": True}, ["carla_mosaic"]),
    "navsim": (
        "navsim",
        {"use_navsim_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True},
        ["front_left", "front", "front_right", "back"],
    ),
    "wod": (
        "wod",
        {"use_waymo_e2e_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True},
        ["front_left", "front", "front_right"],
    ),
}


@dataclass
class Timing:
    """One loader's round: samples, wall and CPU seconds, summed over its slices; ``fastest``: the wall seconds per
    sample of its fastest slice (another process on the core only ever slows a slice down)."""

    samples: int = 0
    wall: float = 0.0
    cpu: float = 0.0
    fastest: float = math.inf

    @property
    def rate(self) -> float:
        return self.samples / self.wall

    def add(self, batches: Iterator[int]) -> None:
        """Run ``batches`` (an iterator over batch sizes) and count it in."""
        wall, cpu = time.perf_counter(), time.process_time()
        samples = sum(batches)
        wall = time.perf_counter() - wall
        self.samples, self.wall, self.cpu = (
            self.samples + samples,
            self.wall + wall,
            self.cpu + time.process_time() - cpu,
        )
        if samples:
            self.fastest = min(self.fastest, wall / samples)


def timed_round(runs: dict[str, Callable[[], Iterator[int]]], steps: int, slices: int) -> dict[str, Timing]:
    """One round of every loader of a kind, ``steps`` batches each, interleaved: each pass is cut into ``slices``
    slices, run in turn (in reverse order every other slice), so a change in the machine's load during the round
    weighs on every loader alike, and a ratio of two loaders is taken over the same stretch of time. A loader with
    dataloader workers runs its pass whole afterwards: its workers would fill their prefetch queue while the other
    loaders' slices run."""
    passes = {name: run() for name, run in runs.items()}
    timings = {name: Timing() for name in runs}
    sliced = [name for name in runs if name != OURS_TWO]
    bounds = [steps * k // slices for k in range(slices + 1)]
    for k, (start, stop) in enumerate(itertools.pairwise(bounds)):
        for name in sliced if k % 2 == 0 else sliced[::-1]:
            gc.collect()  # every slice starts from empty GC generations
            timings[name].add(itertools.islice(passes[name], stop - start))
    for name in set(runs) - set(sliced):
        gc.collect()
        timings[name].add(passes[name])
    return timings


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


def generate_data(kind: str, raw: Path, data: Path, args: argparse.Namespace) -> None:
    """Generated raw data of ``kind`` converted to shards in ``data``."""
    if KINDS[kind][0] == "carla":
        generate(raw, count=args.routes, frames=args.frames, realistic=kind == "realistic")
        adapter = get_adapter("carla_lead")
    elif kind == "navsim":
        navsim.generate(raw, count=args.logs, seed=0)
        adapter = get_adapter("navsim", maps=str(raw / "maps"))
    else:
        wod_e2e.generate(raw, count=args.logs, seed=0, image_scale=args.wod_image_scale)
        adapter = get_adapter("wod_e2e")
    convert(adapter, raw, data)


def loaders(kind: str, tmp: Path, args: argparse.Namespace) -> dict[str, Callable[[], Iterator[int]]]:
    """The loaders over one kind of generated data, as callables that start a pass and yield batch sizes."""
    raw, data = tmp / kind / "raw", tmp / kind / "data"
    generate_data(kind, raw, data, args)
    source, switches, _ = KINDS[kind]
    config = input_spec(LeadConfig(**switches))

    def ours(stream: Iterator[dict[str, Any]]) -> Callable[[], Iterator[int]]:
        return lambda: (len(next(stream)["__key__"]) for _ in range(args.steps))

    runs = {
        PLAIN: lambda: _batched((1 for _ in _samples(data, args)), args.batch_size),
        PIXELS: lambda: _batched((_decode_jpegs(sample) for sample in _samples(data, args)), args.batch_size),
        OURS: ours(training_stream(kind, data, args, config, False, 0)),
    }
    if source in ("carla", "wod"):  # rigs the device lays out: CARLA's mosaic as stored, WOD-E2E's three cameras
        runs[OURS_DEVICE] = ours(training_stream(kind, data, args, config, True, 0))
    if args.two_workers:
        runs[OURS_TWO] = ours(training_stream(kind, data, args, config, False, 2))
    if args.lead_style and source == "carla":
        check_agreement(data, LeadStyleFrames(raw), SourceTransform("carla", config))
        lead = {
            views: DataLoader(LeadStyleFrames(raw, views), args.batch_size, shuffle=True, num_workers=0)
            for views in (1, 2)
        }
        for name, views in ((LEAD_BOTH, 2), (LEAD_ONE, 1)):
            runs[name] = partial(
                lambda views: (len(b["key"]) for _, b in zip(range(args.steps), _forever(lead[views]), strict=False)),
                views,
            )
    return runs


def training_stream(
    kind: str, data: Path, args: argparse.Namespace, config: InputSpec, inputs_on_device: bool, workers: int
) -> Iterator[dict[str, Any]]:
    """One epoch's stream of our training loader, as in training: every round goes on with it."""
    source, _, cameras = KINDS[kind]
    dm = DriveDataModule(
        train={source: SourceSpec([str(data)], cameras=cameras)},
        schedule=MixingSchedule.constant({source: 1.0}, args.batch_size),
        steps_per_epoch=args.steps * (args.rounds + 1) + 1,
        num_workers=workers,
        inputs=config,
        inputs_on_device=inputs_on_device,
    )
    dm.trainer = SimpleNamespace(current_epoch=0, world_size=1)
    wall, cpu = time.perf_counter(), time.process_time()
    stream = iter(dm.train_dataloader()[source])
    first = next(stream)
    print(
        f"{kind}: ours (inputs_on_device={inputs_on_device}, {workers} workers), the shuffle buffer's fill and the "
        f"first batch (once per epoch and worker): {time.perf_counter() - wall:.2f} s wall, "
        f"{time.process_time() - cpu:.2f} s CPU for {len(first['__key__'])}"
    )
    return stream


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--routes", type=int, default=6, help="CARLA routes per CARLA kind")
    parser.add_argument("--frames", type=int, default=16, help="frames per CARLA route")
    parser.add_argument("--logs", type=int, default=8, help="NAVSIM logs / WOD-E2E segments per split")
    parser.add_argument(
        "--wod-image-scale",
        type=float,
        default=1.0,
        help="WOD-E2E camera size as a fraction of the real cameras' (1.0: real size; 0.0556: generator default)",
    )
    parser.add_argument("--batch-size", type=int, default=8)
    parser.add_argument("--steps", type=int, default=40, help="batches per round for ours and the LEAD-style loader")
    parser.add_argument("--rounds", type=int, default=3, help="timed rounds, after one warm-up round")
    parser.add_argument(
        "--slices", type=int, default=8, help="slices of each round, in which the loaders of a kind take turns"
    )
    parser.add_argument("--two-workers", action="store_true", help="also ours with 2 dataloader workers")
    parser.add_argument("--lead-style", action="store_true", help="also the LEAD-style loader (CARLA kinds)")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (collation)")
    parser.add_argument("--kinds", nargs="+", default=["realistic", "navsim", "wod"], choices=list(KINDS))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"load average at start: {' '.join(f'{v:.2f}' for v in os.getloadavg())}; CPUs usable: {_cpus()}")
    with tempfile.TemporaryDirectory() as tmp:
        runs = {kind: loaders(kind, Path(tmp), args) for kind in args.kinds}
        timings: dict[tuple[str, str], list[Timing]] = {(k, n): [] for k, per in runs.items() for n in per}
        gc.collect()
        gc.freeze()  # what the loader's workers do (datamodule._freeze_inherited_objects): see the module docstring
        for round_index in range(-1, args.rounds):  # round -1: the warm-up, not counted
            for kind, per_kind in runs.items():
                for name, timing in timed_round(per_kind, args.steps, args.slices).items():
                    if round_index >= 0:
                        timings[kind, name].append(timing)
                    print(
                        f"round {'warm-up' if round_index < 0 else round_index}, {kind}: {name}: {timing.samples} "
                        f"samples, {timing.rate:.1f} samples/s, {timing.cpu / timing.samples * 1e3:.2f} ms CPU/sample"
                    )
        print(f"load average at end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
        summary(runs, timings, args.rounds)


def summary(
    runs: dict[str, dict[str, Callable[[], Iterator[int]]]], timings: dict[tuple[str, str], list[Timing]], rounds: int
) -> None:
    """Medians over the rounds; each ratio is the median of the per-round ratios, with their spread: by samples/s,
    by CPU time (one process), and of the fastest slices (the least disturbed stretch of each loader's round)."""
    print(
        f"\nmedian over {rounds} rounds; ratio: samples/s over plain decoding's in the same round (spread: max/min-1)"
    )
    for kind in runs:
        source, switches, _ = KINDS[kind]
        print(f"{kind} ({source}, LeadConfig({', '.join(f'{k}={v}' for k, v in switches.items())})):")
        plain = timings[kind, PLAIN]
        for name in runs[kind]:
            of = timings[kind, name]
            rate = statistics.median(t.rate for t in of)
            cpu = statistics.median(t.cpu / t.samples * 1e3 for t in of)
            line = f"  {name}: {rate:.1f} samples/s, {cpu:.2f} ms CPU/sample"
            if name != PLAIN:
                ratios = [x.rate / y.rate for x, y in zip(of, plain, strict=True)]
                spread = max(ratios) / min(ratios) - 1
                line += f", {statistics.median(ratios):.2f}x plain decoding (spread {spread:.0%})"
            if name not in (PLAIN, OURS_TWO):  # one process: CPU per sample, steadier than wall time on a busy machine
                cpu_ratios = [y.cpu / y.samples / (x.cpu / x.samples) for x, y in zip(of, plain, strict=True)]
                cpu_spread = max(cpu_ratios) / min(cpu_ratios) - 1
                line += f", by CPU time {statistics.median(cpu_ratios):.2f}x (spread {cpu_spread:.0%})"
                fastest = [y.fastest / x.fastest for x, y in zip(of, plain, strict=True)]
                line += (
                    f", fastest slices {statistics.median(fastest):.2f}x (spread {max(fastest) / min(fastest) - 1:.0%})"
                )
            print(line)


def _cpus() -> int:
    return len(os.sched_getaffinity(0))


def _samples(data: Path, args: argparse.Namespace) -> Iterator[dict[str, Any]]:
    """As many samples as ours reads in a round (``--steps`` x ``--batch-size``), over the shards again and again:
    both sides of a ratio run equally long over the same kind of samples."""
    passes = itertools.chain.from_iterable(read_samples(data) for _ in itertools.count())
    return itertools.islice(passes, args.steps * args.batch_size)


def _batched(per_sample: Iterator[int], size: int) -> Iterator[int]:
    """Samples counted in batches of ``size``, so plain decoding is sliced in batches as the loaders are."""
    while count := sum(itertools.islice(per_sample, size)):
        yield count


def _decode_jpegs(sample: dict[str, Any]) -> int:
    for name, value in sample.items():
        if name.startswith("cam_"):
            cv2.imdecode(np.frombuffer(value, np.uint8), cv2.IMREAD_COLOR)
    return 1


def _forever(loader: DataLoader):
    while True:
        yield from loader


if __name__ == "__main__":
    main()
