"""The main job, end to end on synthetic data: raw data in all three source formats -> adapters -> shards ->
baseline predictions -> open-loop scores -> a table. Minutes on a laptop CPU; every stage writes real files."""

import importlib
import json
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from lead_s2r.baselines import predict_constant_turn_rate
from lead_s2r.convert import convert
from lead_s2r.predictions import write_predictions
from lead_s2r.registry import get_adapter
from lead_s2r.scoring.run import score_predictions
from lead_s2r.shards import read_samples

#: dataset -> (synthetic log count, adapter options relative to the raw folder, metrics)
PLAN: dict[str, tuple[int, dict[str, str], tuple[str, ...]]] = {
    "carla_lead": (3, {}, ("ade",)),
    "navsim": (2, {"maps": "maps"}, ("ade",)),
    "wod_e2e": (3, {}, ("ade", "rfs@wod-e2e-2025")),
}


def _stage(console: Console, name: str, started: float) -> None:
    console.print(f"[bold green]{name}[/] ({time.perf_counter() - started:.1f} s)")


def quickstart(out: Path, workers: int = 2, console: Console | None = None) -> dict[str, Any]:
    """Run every stage into ``out`` and return the scores per dataset and metric."""
    console = console or Console()
    started = time.perf_counter()
    results: dict[str, Any] = {}
    for dataset, (count, options, metrics) in PLAN.items():
        raw, data = out / "raw" / dataset, out / "data" / dataset
        importlib.import_module(f"lead_s2r.synthetic.{dataset}").generate(raw, count=count, seed=0)
        _stage(console, f"{dataset}: synthetic raw data -> {raw}", started)
        adapter = get_adapter(dataset, **{name: str(raw / value) for name, value in options.items()})
        converted = convert(adapter, raw, data, workers=workers, force=True)
        if not converted.ok:
            raise RuntimeError(f"{dataset}: conversion failed: {converted.errors}")
        _stage(console, f"{dataset}: {converted.samples} samples converted -> {data}", started)
        predictions = [
            predict_constant_turn_rate(sample) for sample in read_samples(data, fields=["future"]) if "future" in sample
        ]
        (out / "predictions").mkdir(parents=True, exist_ok=True)
        predictions_path = write_predictions(out / "predictions" / f"{dataset}.parquet", predictions)
        for metric in metrics:
            scores = out / "scores" / f"{dataset}-{metric}"
            report = score_predictions(metric, predictions_path, [data], scores, allow_missing=True)  # test: no future
            results[f"{dataset} {metric}"] = report["aggregates"]
        _stage(console, f"{dataset}: constant-turn-rate baseline scored ({', '.join(metrics)})", started)
    (out / "summary.json").write_text(json.dumps(results, indent=2))
    console.print(_table(results))
    console.print(
        "Training (TFv6/LTFv6 sim-to-real) joins this pipeline once the data module lands; "
        f"everything above is in {out}."
    )
    return results


def _table(results: dict[str, Any]) -> Table:
    table = Table(title="constant-turn-rate baseline, synthetic data")
    table.add_column("dataset / metric")
    table.add_column("aggregates")
    for name, aggregates in results.items():
        scalars = {k: v for k, v in aggregates.items() if isinstance(v, int | float)}
        table.add_row(
            name, ", ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in scalars.items())
        )
    return table
