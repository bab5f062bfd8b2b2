"""Throughput of ``lead-s2r score`` (PDMS v1.1: a PDM-Closed reference and the prediction's score per sample) in
this process, on 2 local processes, and on Ray with 1 and 2 CPUs; and whether every run wrote the same scores.

Run: ``.venv/bin/python benchmarks/score_scale.py [--logs 12] [--rounds 2]``. Synthetic NAVSIM logs (7 scenes each)
are generated and converted with maps into a temporary folder; the constant-velocity planner is scored. Ray is
started on this machine before the clock starts (the throughput of a running cluster). BLAS threads are pinned to 1.
"""

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"

import argparse  # noqa: E402
import hashlib  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from lead_s2r.convert import convert  # noqa: E402
from lead_s2r.processes import Executor, InlineExecutor, ProcessExecutor, RayExecutor  # noqa: E402
from lead_s2r.registry import get_adapter  # noqa: E402
from lead_s2r.scoring.run import SCORES_TABLE, planner_predictions, score_predictions  # noqa: E402
from lead_s2r.synthetic import navsim as synth  # noqa: E402

METRIC = "pdms@navsim-1.1"
SCORER_MODULE = "lead_s2r.scoring.navsim.pdms_scorer"


def timed(executor: Executor, predictions: Path, data: Path, out: Path) -> tuple[int, float, str]:
    """Samples scored, seconds, sha256 of scores.parquet."""
    start = time.perf_counter()
    report = score_predictions(METRIC, predictions, data, out, executor=executor, allow_missing=True)
    seconds = time.perf_counter() - start
    return report["aggregates"]["frames"], seconds, hashlib.sha256((out / SCORES_TABLE).read_bytes()).hexdigest()


def on_ray(cpus: int, predictions: Path, data: Path, out: Path) -> tuple[int, float, str]:
    import ray

    ray.init(address="local", num_cpus=cpus, include_dashboard=False, log_to_driver=False)
    try:
        return timed(RayExecutor(), predictions, data, out)
    finally:
        ray.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", type=int, default=12)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        raw, data = Path(tmp) / "raw", Path(tmp) / "data"
        synth.generate(raw, count=args.logs, seed=0)
        assert convert(get_adapter("navsim", maps=str(raw / "maps")), raw, data).ok
        predictions = planner_predictions("constant-velocity", data, Path(tmp) / "predictions.parquet")
        runs = {
            "this process": lambda out: timed(InlineExecutor(), predictions, data, out),
            "2 processes": lambda out: timed(ProcessExecutor(2, preload=[SCORER_MODULE]), predictions, data, out),
            "Ray, 1 CPU": lambda out: on_ray(1, predictions, data, out),
            "Ray, 2 CPUs": lambda out: on_ray(2, predictions, data, out),
        }
        for round_index in range(args.rounds):
            digests, base = set(), None
            for name, run in runs.items():
                load = os.getloadavg()[0]
                samples, seconds, digest = run(Path(tmp) / f"scores-{round_index}-{name}")
                digests.add(digest)
                rate = samples / seconds
                base = base or rate
                print(
                    f"round {round_index} {name}: {samples} samples in {seconds:.2f} s = {rate:.1f} samples/s, "
                    f"{rate / base:.2f}x this process; load average {load:.1f}"
                )
            print(f"round {round_index}: the same scores.parquet bytes in every run: {len(digests) == 1}")


if __name__ == "__main__":
    main()
