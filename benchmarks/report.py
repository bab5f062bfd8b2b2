"""``lead-s2r report`` on quickstart-sized held-out data: NAVSIM ``test`` (4 logs) and WOD-E2E ``val`` (24 segments),
converted, predicted by the constant-velocity planner and scored with every metric the quickstart uses; then the
report of 20 sample pages (10 NAVSIM, 10 WOD-E2E) is timed. The acceptance bound is 60 s.

Command: ``.venv/bin/python benchmarks/report.py --out /tmp/report_bench`` (re-runs reuse the converted data).
"""

import argparse
from pathlib import Path

import numpy as np
from cpu_time import timed

from lead_s2r.convert import convert
from lead_s2r.predictions import write_predictions
from lead_s2r.registry import get_adapter
from lead_s2r.report.site import build_report
from lead_s2r.scoring.baselines import predict_constant_velocity
from lead_s2r.scoring.run import score_predictions
from lead_s2r.scoring.scores_file import ScoresFile
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim, wod_e2e

GRIDS = {"navsim": 0.5 * np.arange(1, 9), "wod_e2e": 0.25 * np.arange(1, 21)}
METRICS = {"navsim": ("pdms@navsim-1.1", "epdms@navsim-2.2", "ade"), "wod_e2e": ("rfs@wod-e2e-2025", "ade")}
PAGES_PER_DATASET = {"navsim": ("pdms", 10), "wod_e2e": ("rfs", 10)}


def prepare(out: Path) -> Path:
    """Converted data and a scored run under ``out``; returns the run folder."""
    raw, data, run = out / "raw", out / "data", out / "run"
    if not (data / "wod_e2e" / "manifest.parquet").is_file():
        navsim.generate(raw / "navsim", seed=0, splits={"test": 4})
        wod_e2e.generate(raw / "wod_e2e", seed=0, splits={"val": 24})
        adapter = get_adapter("navsim", maps=str(raw / "navsim" / "maps"))
        convert(adapter, raw / "navsim", data / "navsim", workers=2, force=True)
        convert(get_adapter("wod_e2e"), raw / "wod_e2e", data / "wod_e2e", workers=2, force=True)
    run.mkdir(parents=True, exist_ok=True)
    for dataset, grid in GRIDS.items():
        plans = [predict_constant_velocity(s, grid) for s in read_samples(data / dataset, fields=("future",))]
        predictions = write_predictions(run / f"{dataset}.parquet", plans)
        for metric in METRICS[dataset]:
            folder = run / "scores" / dataset / metric.split("@")[0]
            score_predictions(metric, predictions, [data / dataset], folder, allow_missing=True)
    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("/tmp/report_bench"))
    args = parser.parse_args()
    run = prepare(args.out)
    keys = []
    for dataset, (metric, count) in PAGES_PER_DATASET.items():
        keys += ScoresFile.read(run / "scores" / dataset / metric).table["key"].to_pylist()[:count]
    index, seconds = timed(lambda: build_report(run, args.out / "report", samples=keys))
    pages = len(list((index.parent / "samples").glob("*.html")))
    print(f"report: {pages} sample pages, {len(list((index.parent / 'img').glob('*.png')))} PNGs in {seconds:.1f} s")


if __name__ == "__main__":
    main()
