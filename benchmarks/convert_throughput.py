"""Conversion throughput of an adapter on generated data (LEAD CARLA routes, NAVSIM logs or WOD-E2E segments):
scaling over workers, and CPU by stage.

.venv/bin/python benchmarks/convert_throughput.py --routes 64 --frames 16 --workers 1 2 --rounds 3
.venv/bin/python benchmarks/convert_throughput.py --import-torch --workers 1 2 --rounds 3   # a user's script
.venv/bin/python benchmarks/convert_throughput.py --executor ray --workers 1 2 --rounds 3    # Ray, N CPUs
.venv/bin/python benchmarks/convert_throughput.py --cli --routes 64 --frames 16 --workers 1 2 --rounds 2 --no-stages
    # issue 42's check: `lead-s2r convert` from the shell on 1024 samples, 1 and 2 workers interleaved, best of two
.venv/bin/python benchmarks/convert_throughput.py --dataset navsim --routes 6 --workers 1 --rounds 1 [--no-maps]
.venv/bin/python benchmarks/convert_throughput.py --dataset wod_e2e --routes 4 --image-scale 0.7 --workers 1 --rounds 1

``--dataset`` picks the generator and adapter (``carla_lead``: ``--routes`` routes of ``--frames`` frames, ``--rig``;
``navsim``: ``--routes`` logs of 20 frames, 7 scenes each, with the generated maps unless ``--no-maps``; ``wod_e2e``:
``--routes`` segments of 12 frames per split, JPEGs at ``--image-scale`` of the real cameras, ``--history``). Runs
``convert`` with each worker count in turn, ``--rounds`` times (interleaved, so a machine shared with other jobs slows
every count alike), and reports per round: wall time, samples/s in total and per worker, the CPU seconds of the
driver and of its worker processes, and the speed-up over the first worker count measured in the same round, beside a
machine check (how much faster two processes run a plain CPU loop than one at that moment), and whether every worker
count wrote the same bytes (every file of the converted folder). Then one process converts the data again stage by
stage and splits its CPU time: indexing the logs, the adapter (reading the raw files and building the sample),
schema validation, encoding the fields, writing the tar. Each run loads NAVSIM's maps anew, as a fresh worker does.

``--import-torch`` imports torch first, as a user's training script calling ``convert`` would (the workers must not
pay for it again). ``--cli`` runs each conversion as a user does, ``lead-s2r convert <dataset> --src ... --out ...
--workers N`` in a subprocess (start-up and imports included in its wall time). The summary gives, per worker count,
the median of the same-round speed-ups and the speed-up of its best round over the first count's best round.
``--executor ray`` runs each worker count on a Ray started on this machine with that many CPUs (started before the
clock starts: the throughput of a running cluster).
"""

import argparse
import contextlib
import hashlib
import multiprocessing as mp
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from functools import partial
from pathlib import Path

if "--import-torch" in sys.argv:  # at the top, as in a user's script: whatever re-imports __main__ pays for it
    import torch  # noqa: F401

from cpu_time import local_ray, timed

from lead_s2r.convert import convert, manifest_row, one_thread_per_worker
from lead_s2r.processes import RayExecutor
from lead_s2r.registry import Adapter, get_adapter
from lead_s2r.schema import validate
from lead_s2r.shards import ShardFile, encode_sample, load_manifest
from lead_s2r.synthetic import carla_lead, navsim, wod_e2e
from lead_s2r_adapters import navsim_map


def generate(dataset: str, src: Path, args: argparse.Namespace) -> None:
    """``--routes`` routes, logs or segments of ``dataset``'s generator in ``src``."""
    if dataset == "carla_lead":
        carla_lead.generate(src, count=args.routes, frames=args.frames)
    elif dataset == "navsim":
        navsim.generate(src, count=args.routes)
    else:
        wod_e2e.generate(src, count=args.routes, image_scale=args.image_scale)


def adapter_options(dataset: str, src: Path, args: argparse.Namespace) -> dict[str, object]:
    return {
        "carla_lead": {"rig": args.rig},
        "navsim": {"split": navsim.DATA_SPLIT, "maps": None if args.no_maps else str(src / "maps")},
        "wod_e2e": {"history": args.history},
    }[dataset]


def spin(n: int) -> int:
    total = 0
    for i in range(n):
        total += i
    return total


def machine_parallelism(n: int = 10_000_000) -> float:
    """How much faster two processes run a pure-Python loop than one right now (2.0 on two idle cores): what the
    machine, shared with other jobs, leaves for a 2-worker run."""
    start = time.perf_counter()
    spin(2 * n)
    one = time.perf_counter() - start
    context = mp.get_context("fork")  # no threads in this process yet; the loop needs no imports
    start = time.perf_counter()
    procs = [context.Process(target=spin, args=(n,)) for _ in range(2)]
    for proc in procs:
        proc.start()
    for proc in procs:
        proc.join()
    return one / (time.perf_counter() - start)


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def digests(out: Path) -> dict[str, str]:
    """sha256 of every file of a converted folder, by its path in the folder."""
    return {
        str(path.relative_to(out)): hashlib.sha256(path.read_bytes()).hexdigest()
        for path in sorted(out.rglob("*"))
        if path.is_file()
    }


def run(adapter: Adapter, src: Path, out: Path, workers: int, on_ray: bool) -> dict[str, float]:
    """One conversion: wall time, CPU of this process and of its reaped children (NaN for a process pool's)."""
    with local_ray(workers) if on_ray else contextlib.nullcontext():
        executor = RayExecutor(initializer=one_thread_per_worker) if on_ray else None
        navsim_map.load_map.cache_clear()  # a run in this process loads the maps again, as a fresh worker does
        load = os.getloadavg()[0]
        wall, cpu, child = time.perf_counter(), time.process_time(), children_cpu()
        result = convert(adapter, src, out, workers=workers, force=True, executor=executor)
        wall = time.perf_counter() - wall
    if not result.ok:
        raise RuntimeError(f"conversion failed: {result.errors[:3]}")
    return {
        "samples": result.samples,
        "wall": wall,
        "driver_cpu": time.process_time() - cpu,
        # a pool's workers are the forkserver's children, and it outlives the run: their CPU is not ours to read
        "worker_cpu": float("nan") if workers > 1 and not on_ray else children_cpu() - child,
        "load": load,
    }


def run_cli(dataset: str, src: Path, out: Path, workers: int, options: dict[str, object]) -> dict[str, float]:
    """One conversion by the ``lead-s2r`` command beside this Python: wall time and the CPU of the reaped command."""
    command = [str(Path(sys.executable).with_name("lead-s2r")), "convert", dataset, "--src", str(src)]
    command += ["--out", str(out), "--workers", str(workers), "--force", "--quiet"]
    command += [text for name, value in options.items() if value is not None for text in (f"--{name}", str(value))]
    load = os.getloadavg()[0]
    wall, child = time.perf_counter(), children_cpu()
    subprocess.run(command, check=True)
    wall = time.perf_counter() - wall
    samples = load_manifest(out).num_rows
    return {"samples": samples, "wall": wall, "driver_cpu": 0.0, "worker_cpu": children_cpu() - child, "load": load}


def stage_split(adapter: Adapter, src: Path, out: Path) -> tuple[int, dict[str, float]]:
    """CPU seconds per stage of converting every log in this process (what one worker does)."""
    cpu: dict[str, float] = defaultdict(float)
    count = 0
    out.mkdir(parents=True, exist_ok=True)
    shard = ShardFile(out / "stages-000000.tar")
    logs, cpu["index (list_logs)"] = timed(partial(adapter.list_logs, src), time.process_time)
    for log in logs:
        samples = iter(adapter.iter_samples(log))
        while True:
            sample, cpu_s = timed(partial(next, samples, None), time.process_time)
            cpu["adapter (read + build)"] += cpu_s
            if sample is None:
                break
            cpu["validate"] += timed(partial(validate, sample), time.process_time)[1]
            encode = timed(partial(encode_sample, sample), time.process_time)[1]
            cpu["encode fields (PNG, npy, json)"] += encode
            written = timed(partial(shard.write, sample), time.process_time)[1]  # encodes again: taken off below
            written += timed(partial(manifest_row, sample), time.process_time)[1]
            cpu["tar write + manifest row"] += max(written - encode, 0.0)
            count += 1
    cpu["close (fsync)"] += timed(shard.close, time.process_time)[1]
    return count, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="carla_lead", choices=["carla_lead", "navsim", "wod_e2e"])
    parser.add_argument("--routes", type=int, default=64, help="CARLA routes, NAVSIM logs or WOD-E2E segments")
    parser.add_argument("--frames", type=int, default=16, help="frames per CARLA route")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--rig", default="normal", choices=["normal", "perturbated", "both"])
    parser.add_argument("--no-maps", action="store_true", help="NAVSIM: convert without the map context")
    parser.add_argument("--image-scale", type=float, default=0.7, help="WOD-E2E: JPEG size relative to the real")
    parser.add_argument("--history", type=int, default=0, help="WOD-E2E: previous front images per sample")
    parser.add_argument("--raw", type=Path, help="reuse (or create) the generated data here")
    parser.add_argument("--executor", choices=["processes", "ray"], default="processes")
    parser.add_argument("--import-torch", action="store_true", help="import torch first, as a training script does")
    parser.add_argument("--cli", action="store_true", help="convert with the lead-s2r command, as a user does")
    parser.add_argument("--no-stages", action="store_true", help="skip the CPU split by stage")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src = args.raw or Path(tmp) / "raw"
        if not src.is_dir() or not any(src.iterdir()):
            _, seconds = timed(partial(generate, args.dataset, src, args))
            size = sum(path.stat().st_size for path in src.rglob("*") if path.is_file())
            print(f"generated {args.dataset} x {args.routes} in {seconds:.2f} s, {size / 1e6:.1f} MB")
        options = adapter_options(args.dataset, src, args)
        adapter = get_adapter(args.dataset, **options)
        #: per worker count, each round's (samples/s, speed-up over the first count in the round, ms CPU/sample)
        rounds: dict[int, list[tuple[float, float, float]]] = defaultdict(list)
        for round_index in range(args.rounds):
            print(f"round {round_index}: machine check, 2 processes of a CPU loop: {machine_parallelism():.2f}x one")
            base = None
            written = []
            for workers in args.workers:
                out = Path(tmp) / f"out{workers}"
                if args.cli:
                    r = run_cli(args.dataset, src, out, workers, options)
                else:
                    r = run(adapter, src, out, workers, args.executor == "ray")
                written.append(digests(out))
                rate = r["samples"] / r["wall"]
                base = base or rate
                cpu_ms = (r["driver_cpu"] + r["worker_cpu"]) / r["samples"] * 1e3
                rounds[workers].append((rate, rate / base, cpu_ms))
                print(
                    f"round {round_index} workers={workers}: {r['samples']} samples in {r['wall']:.2f} s = "
                    f"{rate:.1f} samples/s, {rate / workers:.1f} per worker, {rate / base:.2f}x workers="
                    f"{args.workers[0]}; CPU {r['driver_cpu']:.1f} s driver + {r['worker_cpu']:.1f} s workers = "
                    f"{cpu_ms:.1f} ms/sample; load average {r['load']:.1f}"
                )
            same = all(files == written[0] for files in written)
            print(f"round {round_index}: {len(written[0])} files, the same bytes for every worker count: {same}")
        print(f"median over {args.rounds} rounds:")
        best_first = max(rate for rate, _, _ in rounds[args.workers[0]])
        for workers in args.workers:
            rates, speedups, cpu_ms = zip(*rounds[workers], strict=True)
            print(
                f"  workers={workers}: {statistics.median(rate / workers for rate in rates):.1f} samples/s per worker, "
                f"{statistics.median(speedups):.2f}x workers={args.workers[0]} (same-round ratios), "
                f"{statistics.median(cpu_ms):.1f} ms CPU/sample; best round "
                f"{max(rates):.1f} samples/s = {max(rates) / best_first:.2f}x the "
                f"best of workers={args.workers[0]}"
            )
        if args.no_stages:
            return
        count, cpu = stage_split(adapter, src, Path(tmp) / "stages")
        total = sum(cpu.values())
        print(f"CPU by stage, one process, {count} samples: {total / count * 1e3:.2f} ms/sample")
        for stage, seconds in cpu.items():
            print(f"  {stage}: {seconds / count * 1e3:.2f} ms/sample ({seconds / total:.0%})")


if __name__ == "__main__":
    main()
