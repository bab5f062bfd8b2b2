"""Throughput of ``lead-s2r score`` (PDMS v1.1: a PDM-Closed reference and the prediction's score per sample) in
this process, on N local processes (``--workers N``) and on Ray with N CPUs (``--executor ray``); the CPU time of
the driver and of every process under it; and whether every run wrote the same scores.

Run: ``.venv/bin/python benchmarks/score_scale.py [--logs 150] [--workers 1 2] [--rounds 2] [--data DIR]
[--executors processes ray]``.
Synthetic NAVSIM logs (7 scenes each: 150 logs = 1050 samples) are generated and converted with maps (into
``--data`` to keep them for the next run, else a temporary folder); the constant-velocity planner is scored. Each
round starts with a machine check (how much faster two processes run a CPU loop than one right now: 2.0 on two free
cores) and runs every executor in turn, so a machine shared with other jobs slows them alike. Ray is started on this
machine before the clock starts (the throughput of a running cluster). BLAS threads are pinned to 1.
"""

import one_core  # noqa: F401  (first: pins BLAS threads before numpy loads)

# isort: split
import argparse
import contextlib
import hashlib
import os
import tempfile
import threading
from collections.abc import Callable
from functools import partial
from pathlib import Path

import psutil
from convert_throughput import machine_parallelism  # (benchmarks/ is the script's folder)
from cpu_time import local_ray, wall_and_cpu

from lead_s2r.convert import convert
from lead_s2r.processes import Executor, InlineExecutor, ProcessExecutor, RayExecutor
from lead_s2r.registry import get_adapter
from lead_s2r.scoring.run import make_scorer, planner_predictions, score_predictions
from lead_s2r.scoring.scores_file import SCORES_TABLE
from lead_s2r.synthetic import navsim as synth

METRIC = "pdms@navsim-1.1"
SCORER_MODULE = "lead_s2r.scoring.navsim.pdms_scorer"
POLL_S = 0.25


class DescendantsCPU:
    """CPU seconds of every process under this one (Ray's raylet and workers, a pool's forkserver children), polled
    from a thread while a run lasts: ``RUSAGE_CHILDREN`` counts only children this process waited for. A process
    that ends between two polls loses at most :data:`POLL_S` of its CPU."""

    def __init__(self) -> None:
        self.seen: dict[int, float] = {}
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._watch, daemon=True)

    def poll(self) -> float:
        for process in psutil.Process().children(recursive=True):
            try:
                times = process.cpu_times()
            except psutil.Error:
                continue
            self.seen[process.pid] = times.user + times.system
        return sum(self.seen.values())

    def _watch(self) -> None:
        while not self.done.wait(POLL_S):
            self.poll()

    def __enter__(self) -> "DescendantsCPU":
        self.start = self.poll()
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.done.set()
        self.thread.join()
        self.seconds = self.poll() - self.start


def timed(executor: Executor, predictions: Path, data: Path, out: Path) -> dict[str, float]:
    """Samples scored, wall and CPU seconds (driver, processes under it), sha256 of scores.parquet, load average."""
    load = os.getloadavg()[0]
    score = partial(score_predictions, METRIC, predictions, data, out, executor=executor, allow_missing=True)
    with DescendantsCPU() as workers:
        report, wall, driver = wall_and_cpu(score)
    digest = hashlib.sha256((out / SCORES_TABLE).read_bytes()).hexdigest()
    load = max(load, os.getloadavg()[0])
    return {"samples": report["aggregates"]["frames"], "wall": wall, "driver": driver, "workers": workers.seconds,
            "digest": digest, "load": load}  # fmt: skip


def prepare(data: Path, logs: int) -> Path:
    """Converted NAVSIM data (reused if ``data`` holds it) and the constant-velocity planner's predictions."""
    if not (data / "converted" / "manifest.parquet").is_file():
        synth.generate(data / "raw", count=logs, seed=0)
        assert convert(get_adapter("navsim", maps=str(data / "raw" / "maps")), data / "raw", data / "converted").ok
    make_scorer(METRIC)  # imports the scorer's modules here, not in the first timed run
    return planner_predictions("constant-velocity", data / "converted", data / "predictions.parquet")


def executors(kinds: list[str], workers: list[int]) -> dict[str, tuple[Callable[[], Executor], int | None]]:
    """Every executor to time, by name: how to make it, and the CPUs of the Ray it runs on (None: no Ray). Ratios are
    taken against the first of each kind."""
    chosen: dict[str, tuple[Callable[[], Executor], int | None]] = {}
    if "processes" in kinds:
        chosen["this process"] = (InlineExecutor, None)
        for count in (count for count in workers if count > 1):
            chosen[f"{count} processes"] = (partial(ProcessExecutor, count, preload=[SCORER_MODULE]), None)
    if "ray" in kinds:
        for count in workers:
            chosen[f"Ray, {count} CPU"] = (RayExecutor, count)
    return chosen


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", type=int, default=150, help="synthetic NAVSIM logs of 7 samples each")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="process and Ray CPU counts")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--executors", nargs="+", choices=["processes", "ray"], default=["processes", "ray"])
    parser.add_argument("--data", type=Path, help="keep (or reuse) the generated and converted data here")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or Path(tmp) / "data"
        predictions = prepare(data, args.logs)
        for round_index in range(args.rounds):
            print(f"round {round_index}: machine check {machine_parallelism():.2f}x")
            digests, first = set(), {}
            for name, (make, ray_cpus) in executors(args.executors, args.workers).items():
                out = Path(tmp) / f"scores-{round_index}-{name}"
                with local_ray(ray_cpus) if ray_cpus else contextlib.nullcontext():
                    result = timed(make(), predictions, data / "converted", out)
                digests.add(result["digest"])
                rate = result["samples"] / result["wall"]
                base = first.setdefault(name.split(",")[0] if name.startswith("Ray") else "local", rate)
                cpu_ms = (result["driver"] + result["workers"]) / result["samples"] * 1e3
                print(
                    f"round {round_index} {name}: {result['samples']} samples in {result['wall']:.2f} s = "
                    f"{rate:.1f} samples/s, {rate / base:.2f}x the first of its kind; CPU {result['driver']:.1f} s "
                    f"driver + {result['workers']:.1f} s under it = {cpu_ms:.1f} ms/sample; "
                    f"load average {result['load']:.1f}"
                )
            print(f"round {round_index}: the same scores.parquet bytes in every run: {len(digests) == 1}")


if __name__ == "__main__":
    main()
