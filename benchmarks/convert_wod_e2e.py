"""WOD-E2E conversion throughput: the indexing pass, the adapter alone, and ``convert`` end to end, per worker.

Synthetic records are sized like real ones (real shards hold ~770 records in ~1.7 GB, ~2 MB a record): noise
JPEGs at 0.7 of the real resolution compress to roughly that. Run:
``.venv/bin/python benchmarks/convert_wod_e2e.py --segments 4``
"""

import argparse
import tempfile
from pathlib import Path

from cpu_time import timed

from lead_s2r.convert import convert
from lead_s2r.synthetic.wod_e2e import make_dataset, write_dataset
from lead_s2r_adapters.wod_e2e import WodE2EAdapter


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--segments", type=int, default=4, help="segments per split (12 frames each)")
    parser.add_argument("--image-scale", type=float, default=0.7, help="JPEG size relative to the real cameras")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--history", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        src, out = Path(tmp) / "src", Path(tmp) / "out"
        paths = write_dataset(src, make_dataset(args.segments, seed=0, image_scale=args.image_scale))
        size = sum(p.stat().st_size for p in paths)

        adapter = WodE2EAdapter(history=args.history)
        logs, index_s = timed(lambda: adapter.list_logs(src))
        frames = sum(len(log.extra["records"]) for log in logs)
        print(f"records: {frames}, {size / 1e6:.1f} MB, {size / frames / 1e6:.2f} MB/record")
        print(f"index pass: {frames / index_s:.0f} records/s, {size / index_s / 1e6:.0f} MB/s")

        n, adapter_s = timed(lambda: sum(1 for log in logs for _ in adapter.iter_samples(log)))
        print(f"adapter iter_samples (1 process, history={args.history}): {n / adapter_s:.1f} frames/s")

        result, convert_s = timed(lambda: convert(WodE2EAdapter(history=args.history), src, out, workers=args.workers))
        assert result.ok and result.samples == frames, result.errors
        per_worker = result.samples / convert_s / args.workers
        print(f"convert (workers={args.workers}; index, validate, shards): {per_worker:.1f} frames/s/worker")


if __name__ == "__main__":
    main()
