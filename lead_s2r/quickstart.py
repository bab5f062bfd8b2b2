"""The main job, end to end on synthetic data: raw data in all three source formats -> adapters -> shards ->
sim-to-real training of a tiny TFv6 -> predictions -> open-loop scores beside a model-free baseline -> a table.
Minutes on a laptop CPU; every stage writes real files, and the training stage is the smoke recipe run through
the same LightningCLI as ``lead-s2r fit``.

Lightning talks a lot on the console (model summary, tips, deprecation warnings from its dependencies); the
quickstart sends all of it to ``<out>/lightning.log`` so the console shows the stages and the table. The table has
one row per planner x dataset and one column per entry of :data:`METRICS`, so a new metric is one line there.
"""

import importlib
import json
import logging
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from lead_s2r.baselines import predict_constant_turn_rate
from lead_s2r.convert import convert
from lead_s2r.predictions import read_predictions, write_predictions
from lead_s2r.registry import get_adapter
from lead_s2r.scoring.pdms import ReferenceCache
from lead_s2r.scoring.run import score_predictions
from lead_s2r.shards import read_samples
from lead_s2r.training.cli import run_lightning_cli

RECIPE = Path(__file__).resolve().parents[1] / "recipes" / "smoke" / "sim2real.yaml"
#: The trained model predicts on the real datasets' validation data (the smoke recipe's ``data.predict``).
MODEL_DATASETS = ("navsim", "wod_e2e")
#: dataset -> (synthetic log count, adapter options relative to the raw folder)
PLAN: dict[str, tuple[int, dict[str, str]]] = {
    "carla_lead": (3, {}),
    "navsim": (2, {"maps": "maps"}),
    "wod_e2e": (3, {}),
}
BASELINE = "constant turn rate"
MODEL = "TFv6 (smoke run)"
LIGHTNING_LOG = "lightning.log"


@dataclass(frozen=True)
class Metric:
    """One column of the table: the aggregate ``aggregate`` of scorer ``scorer``, on ``datasets`` (None: all)."""

    column: str
    scorer: str
    aggregate: str
    datasets: tuple[str, ...] | None = None

    def applies(self, dataset: str) -> bool:
        return self.datasets is None or dataset in self.datasets


METRICS = (
    Metric("ADE", "ade", "ade"),
    Metric("FDE", "ade", "fde"),
    Metric("RFS", "rfs@wod-e2e-2025", "rfs", ("wod_e2e",)),
    Metric("PDMS", "pdms@navsim-1.1", "pdms", ("navsim",)),
    Metric("EPDMS", "epdms@navsim-2.2", "epdms", ("navsim",)),
)


#: the scorers that plan a PDM-Closed reference per sample (``reference_cache`` option)
REFERENCE_SCORERS = ("pdms@navsim-1.1", "epdms@navsim-2.2")


def scorers_for(dataset: str) -> list[str]:
    """The scorers the table needs on ``dataset``, each once."""
    return list(dict.fromkeys(metric.scorer for metric in METRICS if metric.applies(dataset)))


def _stage(console: Console, name: str, started: float) -> None:
    console.print(f"[bold green]{name}[/] ({time.perf_counter() - started:.1f} s)")


def quickstart(out: Path, workers: int = 2, console: Console | None = None) -> dict[str, Any]:
    """Run every stage into ``out``; return ``{planner: {dataset: {scorer: aggregates}}}`` (also in summary.json)."""
    console = console or Console()
    started = time.perf_counter()
    results: dict[str, Any] = {BASELINE: {}}
    references = {dataset: ReferenceCache() for dataset in PLAN}
    for dataset, (count, options) in PLAN.items():
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
        path = write_predictions(out / "predictions" / f"{dataset}.parquet", predictions)
        baseline = out / "scores" / "baseline" / dataset
        results[BASELINE][dataset] = score(path, data, dataset, baseline, references[dataset])
        _stage(console, f"{dataset}: {BASELINE} baseline scored ({', '.join(scorers_for(dataset))})", started)
    run = out / "runs" / "sim2real"
    train_and_predict(out, run, console, started)
    results[MODEL] = score_by_dataset(run, out, references)
    _stage(console, f"{MODEL}: predictions scored", started)
    (out / "summary.json").write_text(json.dumps(results, indent=2))
    console.print(table(results))
    console.print(
        f"The {MODEL} rows come from a seconds-long run on a few dozen synthetic samples: they show that every "
        "stage works end to end, not what TFv6 can do.\n"
        f"Data and scores: {out}; summary: {out / 'summary.json'}; training config: {out / 'sim2real.yaml'}\n"
        f"Checkpoints: {run / 'checkpoints'}; predictions: {run / 'predictions.parquet'}; "
        f"metrics: {run / 'lightning_logs'}; Lightning's console output: {out / LIGHTNING_LOG}"
    )
    return results


def score(predictions: Path, data: Path, dataset: str, out: Path, references: ReferenceCache) -> dict[str, Any]:
    """Every scorer the table needs on ``dataset`` (converted in ``data``): ``{scorer: aggregates}``; files under
    ``out/<scorer>``. ``references``: the PDM-Closed references planned on ``data``; a reference depends on the
    scene only, so PDMS and EPDMS, baseline and model, plan each sample's once (the quickstart's slowest step)."""
    results = {}
    for scorer in scorers_for(dataset):
        options = {"reference_cache": references} if scorer in REFERENCE_SCORERS else {}
        # allow_missing: test samples have no future
        report = score_predictions(scorer, predictions, [data], out / scorer, allow_missing=True, **options)
        results[scorer] = report["aggregates"]
    return results


def rooted_recipe(out: Path) -> Path:
    """The smoke recipe with its ``quickstart/`` paths moved under ``out``, written to ``out/sim2real.yaml``."""
    if not RECIPE.exists():
        raise FileNotFoundError(f"{RECIPE} not found: run the quickstart from a source checkout (pip install -e .)")
    config = out / "sim2real.yaml"
    config.write_text(RECIPE.read_text().replace("quickstart/", f"{out.as_posix()}/"))
    return config


@contextmanager
def lightning_output_to(log: Path) -> Iterator[None]:
    """Send Lightning's log records, warnings and anything printed (its rich model summary) to ``log``."""
    loggers = [logging.getLogger(name) for name in ("lightning.pytorch", "lightning.fabric")]
    handlers = [list(logger.handlers) for logger in loggers]
    with log.open("a") as file, redirect_stdout(file), redirect_stderr(file), warnings.catch_warnings():
        warnings.simplefilter("default")  # shown once per place, into the log file
        for logger in loggers:
            logger.handlers = [logging.StreamHandler(file)]
        try:
            yield
        finally:
            for logger, saved in zip(loggers, handlers, strict=True):
                logger.handlers = saved


def train_and_predict(out: Path, run: Path, console: Console, started: float) -> None:
    """Fit the smoke recipe (CARLA perception, NAVSIM + WOD-E2E driving) into ``run``, then predict with it."""
    config = rooted_recipe(out)
    with lightning_output_to(out / LIGHTNING_LOG):
        run_lightning_cli(["fit", "--config", str(config)])
    _stage(console, f"{MODEL} trained -> {run / 'checkpoints'}", started)
    with lightning_output_to(out / LIGHTNING_LOG):
        run_lightning_cli(["predict", "--config", str(config), "--ckpt_path", str(run / "checkpoints" / "last.ckpt")])
    _stage(console, f"{MODEL} predicted -> {run / 'predictions.parquet'}", started)


def score_by_dataset(run: Path, out: Path, references: dict[str, ReferenceCache]) -> dict[str, Any]:
    """Split the model's predictions by dataset and score each part against that dataset alone."""
    predictions = read_predictions(run / "predictions.parquet")
    (run / "predictions").mkdir(exist_ok=True)
    results = {}
    for dataset in MODEL_DATASETS:
        path = write_predictions(
            run / "predictions" / f"{dataset}.parquet", [p for p in predictions if p.dataset == dataset]
        )
        results[dataset] = score(path, out / "data" / dataset, dataset, run / "scores" / dataset, references[dataset])
    return results


def table(results: dict[str, Any]) -> Table:
    """One row per planner x dataset, one right-aligned column per :data:`METRICS` entry ("-": not scored)."""
    grid = Table(title="open-loop scores on synthetic data")
    grid.add_column("planner")
    grid.add_column("dataset")
    grid.add_column("samples", justify="right")
    for metric in METRICS:
        grid.add_column(metric.column, justify="right")
    for planner, datasets in results.items():
        for dataset, scores in datasets.items():
            frames = next(iter(scores.values()), {}).get("frames", "")
            cells = [_cell(scores.get(metric.scorer, {}).get(metric.aggregate)) for metric in METRICS]
            grid.add_row(planner, dataset, str(frames), *cells)
    return grid


def _cell(value: Any) -> str:
    return f"{value:.3f}" if isinstance(value, int | float) else "-"
