"""Conversion throughput of the LEAD CARLA adapter on generated routes: samples/s in total and per worker.

.venv/bin/python benchmarks/convert_carla_lead.py --routes 6 --frames 16 --workers 1 2
"""

import argparse
import tempfile
import time
from pathlib import Path

from lead_s2r.convert import convert
from lead_s2r.registry import get_adapter
from lead_s2r.synthetic.carla_lead import generate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--routes", type=int, default=6)
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--rig", default="normal", choices=["normal", "perturbated", "both"])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / "raw"
        started = time.perf_counter()
        generate(src, count=args.routes, frames=args.frames)
        print(f"generated {args.routes} routes x {args.frames} frames in {time.perf_counter() - started:.2f} s")
        adapter = get_adapter("carla_lead", rig=args.rig)
        started, count = time.perf_counter(), 0
        for log in adapter.list_logs(src):
            count += sum(1 for _ in adapter.iter_samples(log))
        print(f"adapter iter_samples alone (1 process): {count / (time.perf_counter() - started):.1f} samples/s")
        for workers in args.workers:
            out = Path(tmp) / f"out{workers}"
            started = time.perf_counter()
            result = convert(adapter, src, out, workers=workers)
            elapsed = time.perf_counter() - started
            rate = result.samples / elapsed
            print(
                f"rig={args.rig} workers={workers}: {result.samples} samples in {elapsed:.2f} s = "
                f"{rate:.1f} samples/s, {rate / workers:.1f} samples/s per worker"
            )


if __name__ == "__main__":
    main()
