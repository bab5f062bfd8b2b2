"""Training-loader throughput at paper sizes against plain shard decoding, side by side in one process.

.venv/bin/python benchmarks/loader.py --kinds realistic navsim wod --steps 40 --rounds 3 --two-workers

One core: every loader but the 2-worker one runs in this one process (no dataloader workers, one torch thread).

Prints, per kind of generated data, the median over ``--rounds`` rounds (after one warm-up round) of: plain shard
decoding's samples/s (webdataset's tar reader over the converted shards, every field decoded, JPEG bytes left as
bytes: what ``read_samples`` did up to e98a452, the issue's baseline); our training loader's; and their ratio, measured
in the same round, with the spread of that ratio over the rounds. Since then every reader of ours reads tars with
``shards.TarSamples`` (only the members it decodes, each in one read; docs/benchmarks.md, "Eighth round"), so plain
decoding through it (``read_samples``) is printed too, with each loader's ratio to it. The headline rate is
by CPU time: samples per CPU second of the process, i.e. samples/s on a core of its own. On a shared machine the wall
rate also counts the time the process waited for its core while other processes ran (the kernel's run delay), and how
much of that lands on which side moved the wall ratio by up to 44% between runs; so the wall rate and ratio are printed
beside it, and so is each loader's time off the CPU that is not such a wait (``blocked``: reading a file, waiting on a
lock or another thread), which the CPU rate would hide; it is below 0.1 ms a sample for every loader here. Kinds:

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

Ours is ``DriveDataModule``'s training loader (shard resampling, reading the members of the fields the transform reads,
shuffle buffer, decoding them, ``SourceTransform``, collation into batches of ``--batch-size``); one epoch's stream
serves every round, as in training: the shuffle buffer fills once (timed and printed apart). ``--two-workers`` adds ours
with 2 dataloader workers (``--steps`` batches a round, by wall time: its workers' CPU is not this process's; its ratio
is to plain decoding in one process). ``--lead-style`` adds, for the CARLA kinds, ``lead_style.LeadStyleFrames`` over
the raw route folders (LEAD's per-frame steps and tensor contract, both rigs as LEAD builds them uncached, and one
rig), checked against ours on one frame.

Within a round the loaders of a kind take turns: ``--slices`` turns (24), in each of which every loader (plain
decoding, ours, ours for the GPU, then back) runs for ``--slice-seconds`` of CPU time (0.1 s), so each gets the same
CPU time, 2.4 s a round, and a change in the shared machine's load weighs on every side of a ratio alike
(docs/benchmarks.md, "Fifth round" and "Sixth round": 24 turns of 0.1 s spread the ratios over the rounds by 4%, a
round of 320 samples a loader by up to 44%). Every loader is one stream that the rounds go on with: plain decoding
cycles over the shards, ours is one long epoch. The process's Python heap is frozen before the first round
(``gc.freeze``, as the loader's workers do) and collected before every slice: otherwise the occasional full
collection over the half a million objects torch, Lightning and the generated data leave (0.2 s of CPU) lands in
whichever pass is running (docs/benchmarks.md, "Third round").

Torch runs one intra-op thread (``--threads``), as a dataloader worker does. CPU time is this process's (user +
system, every thread).
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
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import torch
import webdataset as wds
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
from lead_s2r.shards import (
    ManifestCheck,
    check_listed_shards,
    decode_sample,
    listed_keys,
    read_samples,
    shard_paths,
)
from lead_s2r.synthetic import navsim, wod_e2e
from lead_s2r.synthetic.carla_lead import generate

PLAIN, PLAIN_OURS, PIXELS, OURS, OURS_DEVICE, OURS_TWO, LEAD_BOTH, LEAD_ONE = (
    "plain decoding (webdataset's tar reader, every field)",
    "plain decoding through our tar reader (read_samples, every field)",
    "plain decoding + JPEG to pixels",
    "ours (DriveDataModule), everything in the loader",
    "ours, camera JPEGs and LiDAR points left for the GPU (inputs_on_device)",
    "ours, 2 workers (samples/s of both, by wall time)",
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
    """One loader's round: samples, wall, CPU and run-queue seconds, summed over its slices."""

    samples: int = 0
    wall: float = 0.0
    cpu: float = 0.0
    waiting: float = 0.0

    @property
    def rate(self) -> float:
        return self.samples / self.wall

    @property
    def cpu_rate(self) -> float:
        """Samples per CPU second of this process (every thread): its samples/s on a core of its own, as long as it
        is not blocked (:attr:`blocked`, printed beside it)."""
        return self.samples / self.cpu

    @property
    def blocked(self) -> float:
        """Seconds off the CPU other than waiting for it: blocked on a file, a lock or another thread (for plain
        decoding: pyarrow's reader threads, which read the manifest on each pass and wait for the core in turn)."""
        return self.wall - self.cpu - self.waiting

    def add(self, batches: Iterator[int], cpu_budget: float = math.inf) -> None:
        """Take batches (their sizes) from ``batches`` until it ends or ``cpu_budget`` CPU seconds are spent."""
        waiting, wall, cpu = _run_delay(), time.perf_counter(), time.process_time()
        samples = 0
        for size in batches:
            samples += size
            if time.process_time() - cpu >= cpu_budget:
                break
        self.samples += samples
        self.wall += time.perf_counter() - wall
        self.cpu += time.process_time() - cpu
        self.waiting += _run_delay() - waiting


def _run_delay() -> float:
    """Seconds this thread has spent runnable but waiting for a CPU (``/proc/thread-self/schedstat``, Linux; 0.0
    elsewhere, where the own-core rate is then the wall rate)."""
    try:
        with open("/proc/thread-self/schedstat") as stat:
            return int(stat.read().split()[1]) / 1e9
    except OSError:
        return 0.0


def timed_round(runs: dict[str, Iterator[int]], args: argparse.Namespace) -> dict[str, Timing]:
    """One round of every loader of a kind, interleaved: ``--slices`` turns, in each of which every loader runs for
    ``--slice-seconds`` of CPU (in reverse order every other turn), so every loader gets the same CPU time and a
    change in the machine's load during the round weighs on every loader alike. A loader with dataloader workers
    runs ``--steps`` batches whole afterwards: its workers would fill their prefetch queue while the other loaders'
    slices run."""
    timings = {name: Timing() for name in runs}
    sliced = [name for name in runs if name != OURS_TWO]
    for turn in range(args.slices):
        for name in sliced if turn % 2 == 0 else sliced[::-1]:
            gc.collect()  # every slice starts from empty GC generations
            timings[name].add(runs[name], args.slice_seconds)
    if OURS_TWO in runs:
        gc.collect()
        timings[OURS_TWO].add(itertools.islice(runs[OURS_TWO], args.steps))
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


def loaders(kind: str, tmp: Path, args: argparse.Namespace) -> dict[str, Iterator[int]]:
    """The loaders over one kind of generated data, each an endless stream of batch sizes that every round goes on
    with (ours: one epoch's stream, as in training)."""
    raw, data = tmp / kind / "raw", tmp / kind / "data"
    generate_data(kind, raw, data, args)
    source, switches, _ = KINDS[kind]
    config = input_spec(LeadConfig(**switches))

    def ours(inputs_on_device: bool, workers: int) -> Iterator[int]:
        return (len(batch["__key__"]) for batch in training_stream(kind, data, args, config, inputs_on_device, workers))

    runs = {
        PLAIN: _batched((1 for _ in _samples(data)), args.batch_size),
        PLAIN_OURS: _batched((1 for _ in _samples(data, read_samples)), args.batch_size),
        PIXELS: _batched((_decode_jpegs(sample) for sample in _samples(data)), args.batch_size),
        OURS: ours(False, 0),
    }
    if source in ("carla", "wod"):  # rigs the device lays out: CARLA's mosaic as stored, WOD-E2E's three cameras
        runs[OURS_DEVICE] = ours(True, 0)
    if args.two_workers:
        runs[OURS_TWO] = ours(False, 2)
    if args.lead_style and source == "carla":
        check_agreement(data, LeadStyleFrames(raw), SourceTransform("carla", config))
        for name, views in ((LEAD_BOTH, 2), (LEAD_ONE, 1)):
            lead = DataLoader(LeadStyleFrames(raw, views), args.batch_size, shuffle=True, num_workers=0)
            runs[name] = (len(batch["key"]) for batch in itertools.chain.from_iterable(itertools.repeat(lead)))
    return runs


def training_stream(
    kind: str, data: Path, args: argparse.Namespace, config: InputSpec, inputs_on_device: bool, workers: int
) -> Iterator[dict[str, Any]]:
    """One epoch's stream of our training loader (longer than the benchmark), as in training: the shuffle buffer
    fills once (timed here), and every round goes on with it."""
    source, _, cameras = KINDS[kind]
    dm = DriveDataModule(
        train={source: SourceSpec([str(data)], cameras=cameras)},
        schedule=MixingSchedule.constant({source: 1.0}, args.batch_size),
        steps_per_epoch=10**6,  # more batches than any run takes
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
    parser.add_argument("--steps", type=int, default=40, help="batches per round of ours with 2 workers")
    parser.add_argument("--rounds", type=int, default=3, help="timed rounds, after one warm-up round")
    parser.add_argument("--slices", type=int, default=24, help="turns of each round, in which the loaders take turns")
    parser.add_argument("--slice-seconds", type=float, default=0.1, help="CPU seconds of each loader's turn")
    parser.add_argument("--two-workers", action="store_true", help="also ours with 2 dataloader workers")
    parser.add_argument("--lead-style", action="store_true", help="also the LEAD-style loader (CARLA kinds)")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (collation)")
    parser.add_argument("--kinds", nargs="+", default=["realistic", "navsim", "wod"], choices=list(KINDS))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    cpus = len(os.sched_getaffinity(0))
    print(f"load average at start: {' '.join(f'{v:.2f}' for v in os.getloadavg())}; CPUs usable: {cpus}")
    with tempfile.TemporaryDirectory() as tmp:
        runs = {kind: loaders(kind, Path(tmp), args) for kind in args.kinds}
        timings: dict[tuple[str, str], list[Timing]] = {(k, n): [] for k, per in runs.items() for n in per}
        gc.collect()
        gc.freeze()  # what the loader's workers do (datamodule._freeze_inherited_objects): see the module docstring
        for round_index in range(-1, args.rounds):  # round -1: the warm-up, not counted
            for kind, per_kind in runs.items():
                for name, timing in timed_round(per_kind, args).items():
                    if round_index >= 0:
                        timings[kind, name].append(timing)
                    print(
                        f"round {'warm-up' if round_index < 0 else round_index}, {kind}: {name}: {timing.samples} "
                        f"samples, {timing.cpu / timing.samples * 1e3:.2f} ms CPU/sample, {timing.rate:.1f} samples/s "
                        f"wall, blocked {timing.blocked / timing.samples * 1e3:.2f} ms/sample"
                    )
        print(f"load average at end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
        summary(runs, timings, args.rounds)


def summary(
    runs: dict[str, dict[str, Iterator[int]]], timings: dict[tuple[str, str], list[Timing]], rounds: int
) -> None:
    """Medians over the rounds; each ratio is the median of the per-round ratios to plain decoding's, with their
    spread: by CPU time (the headline: samples/s on a core of its own, :attr:`Timing.cpu_rate`) and by wall time."""
    print(f"\nmedian over {rounds} rounds; ratios to plain decoding in the same round (spread: max/min - 1)")
    for kind in runs:
        source, switches, _ = KINDS[kind]
        print(f"{kind} ({source}, LeadConfig({', '.join(f'{k}={v}' for k, v in switches.items())})):")
        plain = timings[kind, PLAIN]
        for name in runs[kind]:
            of = timings[kind, name]
            wall = f"{statistics.median(t.rate for t in of):.1f} samples/s wall"
            if name == OURS_TWO:  # its workers' CPU is not this process's: wall time only
                print(f"  {name}: {wall}, {_ratio(of, plain, lambda t: t.rate)} plain decoding by wall samples/s")
                continue
            line = (
                f"  {name}: {statistics.median(t.cpu_rate for t in of):.1f} samples/s on a core of its own "
                f"({statistics.median(t.cpu / t.samples * 1e3 for t in of):.2f} ms CPU/sample, blocked "
                f"{statistics.median(t.blocked / t.samples * 1e3 for t in of):.2f} ms/sample), {wall}"
            )
            if name != PLAIN:
                line += (
                    f"; {_ratio(of, plain, lambda t: t.cpu_rate)} plain decoding by CPU time, "
                    f"{_ratio(of, plain, lambda t: t.rate)} by wall samples/s"
                )
            if name not in (PLAIN, PLAIN_OURS):
                line += f"; {_ratio(of, timings[kind, PLAIN_OURS], lambda t: t.cpu_rate)} {PLAIN_OURS} by CPU time"
            print(line)


def _ratio(ours: list[Timing], plain: list[Timing], rate: Callable[[Timing], float]) -> str:
    """The median over the rounds of ``rate(ours) / rate(plain)`` in each round, with its spread."""
    ratios = [rate(x) / rate(y) for x, y in zip(ours, plain, strict=True)]
    return f"{statistics.median(ratios):.2f}x (spread {max(ratios) / min(ratios) - 1:.0%})"


def _samples(data: Path, read: Callable[[Path], Iterator[dict[str, Any]]] | None = None) -> Iterator[dict[str, Any]]:
    """Every sample of the shards, every field decoded, over and over: one ``read`` (default: webdataset's reader)
    a pass."""
    return itertools.chain.from_iterable(map(read or _webdataset_pass, itertools.repeat(data)))


def _webdataset_pass(data: Path) -> Iterator[dict[str, Any]]:
    """One pass as ``read_samples`` made it up to e98a452, with webdataset's own tar reader: the issue's baseline,
    which every ratio keeps."""
    listed = listed_keys(data)
    shards = shard_paths(data)
    check_listed_shards(listed)
    dataset = wds.WebDataset(
        shards,
        shardshuffle=False,
        empty_check=False,
        nodesplitter=None,
        workersplitter=None,
        handler=wds.reraise_exception,
    )
    return (decode_sample(raw) for raw in ManifestCheck(listed)(dataset))


def _batched(per_sample: Iterator[int], size: int) -> Iterator[int]:
    """Samples counted in batches of ``size``, so plain decoding is sliced in batches as the loaders are."""
    while count := sum(itertools.islice(per_sample, size)):
        yield count


def _decode_jpegs(sample: dict[str, Any]) -> int:
    for name, value in sample.items():
        if name.startswith("cam_"):
            cv2.imdecode(np.frombuffer(value, np.uint8), cv2.IMREAD_COLOR)
    return 1


if __name__ == "__main__":
    main()
