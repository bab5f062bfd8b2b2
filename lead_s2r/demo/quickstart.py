"""The main job, end to end on synthetic data: raw data in all three source formats -> adapters -> shards -> the
real-data experiments of the paper's Table 4 as smoke runs (Ego MLP, LTFv6, LTFv6 + LEAD on NAVSIM and WOD-E2E) ->
predictions on held-out logs -> open-loop scores -> the table in the paper's layout, with the logged human ("Expert")
and every model before and after training. Minutes on a laptop CPU; every stage writes real files, and each training
is a smoke twin of a paper recipe run through the same LightningCLI as ``lead-s2r fit``.

The traps: a model judged on the logs it trained on looks better than it is, so the models train on NAVSIM
``trainval`` / WOD-E2E ``train`` and are scored on NAVSIM ``test`` / WOD-E2E ``val`` logs only, which the generators
draw from the same distribution as the training logs. And a few optimizer steps teach a model nothing, so the
quickstart trains the smoke twins for :data:`STEPS` steps (they run a handful in the test suite) and reports every
model before training too: the two rows show what training changed.

The "without LEAD" rows are the LEAD twins with the synthetic CARLA data taken out (no CARLA source, no
``init_from`` of a CARLA pre-training), so the two rows differ in nothing else. Lightning talks a lot on the console
(model summary, tips, deprecation warnings from its dependencies); the quickstart sends all of it to
``<out>/lightning.log`` so the console shows the stages and the table. Columns are :data:`METRICS`, one per metric and
dataset, so a new metric is one line there. The files under ``<out>/table`` hold Table 4's single layout (every
column, ours and the paper's); the console splits it into one table per dataset with short row names, because nine
columns squeezed into an 80-column terminal cut every header and wrap every model name over four lines.
"""

import importlib
import json
import logging
import shutil
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from rich.console import Console
from rich.table import Table

from lead_s2r.convert import convert
from lead_s2r.predictions import read_predictions, write_predictions
from lead_s2r.registry import get_adapter
from lead_s2r.report.tables import (
    Cell,
    Column,
    Row,
    Run,
    TableSpec,
    collect,
    format_cell,
    load_spec,
    to_csv,
    to_latex,
    to_markdown,
)
from lead_s2r.scoring.baselines import predict_human
from lead_s2r.scoring.navsim.proposals import ReferenceCache
from lead_s2r.scoring.run import score_predictions
from lead_s2r.shards import read_samples
from lead_s2r.training.cli import run_lightning_cli

SMOKE = Path(__file__).resolve().parents[2] / "recipes" / "smoke"
#: dataset -> (synthetic logs per split, adapter options relative to the raw folder). One distribution per dataset;
#: enough logs that a model learns something that carries over to the held-out split. WOD-E2E rates one frame per
#: validation segment, as the real data does, so RFS is a mean over about as many frames as there are val segments.
PLAN: dict[str, tuple[dict[str, int] | None, dict[str, str]]] = {
    "carla_lead": (None, {}),
    "navsim": ({"trainval": 12, "test": 4}, {"maps": "maps"}),
    "wod_e2e": ({"train": 48, "val": 24}, {}),
}
#: dataset -> the held-out split every row is scored on, and its name in the table.
EVAL_SPLITS = {"navsim": "test", "wod_e2e": "val"}
LABELS = {"navsim": "NAVSIM", "wod_e2e": "WOD-E2E"}
#: dataset -> the horizon its scorers read (s): the Expert replays that much of the logged future.
HORIZONS = {"navsim": 4.0, "wod_e2e": 5.0}
#: Training name -> its length in the quickstart: (epochs, optimizer steps per epoch). The Ego MLP's steps cost
#: next to nothing and it needs a few hundred to fit the WOD-E2E futures; the LTFv6 twins cost most of the run.
STEPS: dict[str, tuple[int, int]] = {
    "ego_mlp": (8, 50),
    "navsim_ltfv6": (4, 15),
    "navsim_ltfv6_lead": (4, 15),
    "wod_ltfv6_pretrain": (4, 15),
    "wod_ltfv6": (6, 25),
    "wod_ltfv6_lead": (6, 25),
}
#: Where the paper has no number (the blank :func:`lead_s2r.report.tables.layout` writes too).
PAPER_BLANK = "–"
LIGHTNING_LOG = "lightning.log"


@dataclass(frozen=True)
class Training:
    """One smoke run: the twin it is made from and whether LEAD's synthetic CARLA data is taken out of it."""

    name: str
    recipe: str
    without_lead: bool = False
    predicts: bool = True


#: In init_from order.
TRAININGS = (
    Training("ego_mlp", "ego_mlp"),
    Training("navsim_ltfv6", "navsim_ltfv6_lead", without_lead=True),
    Training("navsim_ltfv6_lead", "navsim_ltfv6_lead"),
    Training("wod_ltfv6_pretrain", "wod_ltfv6_pretrain", predicts=False),
    Training("wod_ltfv6", "wod_ltfv6_lead", without_lead=True),
    Training("wod_ltfv6_lead", "wod_ltfv6_lead"),
)
#: Table row -> the run that makes it on each dataset (the paper's Table 4 trains one model per benchmark).
MODELS: dict[str, dict[str, str]] = {
    "Ego MLP": {"navsim": "ego_mlp", "wod_e2e": "ego_mlp"},
    "LTFv6": {"navsim": "navsim_ltfv6", "wod_e2e": "wod_ltfv6"},
    "LTFv6 + LEAD": {"navsim": "navsim_ltfv6_lead", "wod_e2e": "wod_ltfv6_lead"},
}
EXPERT = "Expert (logged)"
UNTRAINED = "untrained"
BEFORE_TRAINING = "before training"
TRAINED = "trained"


@dataclass(frozen=True)
class Metric:
    """One metric of the table: the aggregate ``aggregate`` of scorer ``scorer`` times ``scale``, on ``datasets``
    (None: every evaluated dataset); one column per dataset."""

    column: str
    scorer: str
    aggregate: str
    datasets: tuple[str, ...] | None = None
    scale: float = 1.0

    def applies(self, dataset: str) -> bool:
        return self.datasets is None or dataset in self.datasets


METRICS = (
    Metric("PDMS", "pdms@navsim-1.1", "pdms", ("navsim",), scale=100.0),
    Metric("EPDMS", "epdms@navsim-2.2", "epdms", ("navsim",), scale=100.0),
    Metric("RFS", "rfs@wod-e2e-2025", "rfs", ("wod_e2e",)),
    Metric("ADE", "ade", "ade"),
    Metric("FDE", "ade", "fde"),
)


#: the scorers that plan a PDM-Closed reference per sample (``reference_cache`` option)
REFERENCE_SCORERS = ("pdms@navsim-1.1", "epdms@navsim-2.2")


def scorers_for(dataset: str) -> list[str]:
    """The scorers the table needs on ``dataset``, each once."""
    return list(dict.fromkeys(metric.scorer for metric in METRICS if metric.applies(dataset)))


def _stage(console: Console, name: str, started: float) -> None:
    console.print(f"[bold green]{name}[/] ({time.perf_counter() - started:.1f} s)")


def quickstart(out: Path, workers: int = 2, console: Console | None = None) -> dict[str, Any]:
    """Run every stage into ``out``; return ``{run id: {dataset: {scorer: aggregates}}}`` (also in summary.json),
    where a run id is ``<training>/trained``, ``<training>/untrained`` or ``expert``."""
    console = console or Console()
    started = time.perf_counter()
    for dataset in PLAN:
        prepare(dataset, out, workers, console, started)
    references = {dataset: ReferenceCache() for dataset in PLAN}
    results = {"expert": score_expert(out, references)}
    _stage(console, f"{EXPERT}: logged futures scored on the held-out logs", started)
    for training in TRAININGS:
        results.update(train_and_score(training, out, console, started, references))
    (out / "summary.json").write_text(json.dumps(results, indent=2))
    spec = table_spec()
    cells = collect(spec, table_runs(results, out))
    (out / "table").mkdir(exist_ok=True)
    for suffix, render in (("md", to_markdown), ("tex", to_latex), ("csv", to_csv)):
        (out / "table" / f"table4.{suffix}").write_text(render(spec, cells))
    for grid in tables(spec, cells):
        console.print(grid)
    console.print(spec.notes)
    console.print(
        f"Trained {steps_range()} optimizer steps on NAVSIM trainval / WOD-E2E train logs, scored on the held-out "
        f"NAVSIM {EVAL_SPLITS['navsim']} / WOD-E2E {EVAL_SPLITS['wod_e2e']} logs; the paper's numbers are on real "
        "data.\n"
        f"Table (markdown, LaTeX, CSV): {out / 'table'}; summary: {out / 'summary.json'}; runs (configs, checkpoints, "
        f"predictions, scores): {out / 'runs'}; Lightning's console output: {out / LIGHTNING_LOG}"
    )
    console.print(f"Report (open in a browser): {write_report(out)}")
    return results


def write_report(out: Path) -> Path:
    """The web report of the Ego MLP, the one model scored on both datasets, against the logged human (the Expert
    row) as baseline: where the model loses to the human, sample by sample. Returns its ``index.html``."""
    from lead_s2r.report.site import build_report

    return build_report(out / "runs" / "ego_mlp" / TRAINED, out / "report", baseline=out / "runs" / "expert", worst=4)


def steps_range() -> str:
    """The fewest to the most optimizer steps a quickstart training takes, as ``60-400``."""
    totals = sorted(epochs * steps for epochs, steps in STEPS.values())
    return f"{totals[0]}-{totals[-1]}" if totals[0] != totals[-1] else str(totals[0])


def prepare(dataset: str, out: Path, workers: int, console: Console, started: float) -> None:
    """Synthetic raw data of ``dataset`` -> ``out/raw/<dataset>`` -> converted ``out/data/<dataset>``."""
    splits, options = PLAN[dataset]
    raw, data = out / "raw" / dataset, out / "data" / dataset
    generator = importlib.import_module(f"lead_s2r.synthetic.{dataset}")
    generator.generate(raw, seed=0, **({} if splits is None else {"splits": splits}))
    _stage(console, f"{dataset}: synthetic raw data -> {raw}", started)
    adapter = get_adapter(dataset, **{name: str(raw / value) for name, value in options.items()})
    converted = convert(adapter, raw, data, workers=workers, force=True)
    if not converted.ok:
        raise RuntimeError(f"{dataset}: conversion failed: {converted.errors}")
    _stage(console, f"{dataset}: {converted.samples} samples converted -> {data}", started)


def score_expert(out: Path, references: dict[str, ReferenceCache]) -> dict[str, Any]:
    """The logged human trajectory (NAVSIM's HumanAgent) on every held-out sample, scored like a model."""
    results = {}
    (out / "runs" / "expert").mkdir(parents=True, exist_ok=True)
    for dataset, split in EVAL_SPLITS.items():
        data = out / "data" / dataset
        held_out = (s for s in read_samples(data, fields=["future"]) if s["meta"]["split"] == split)
        path = write_predictions(
            out / "runs" / "expert" / f"{dataset}.parquet", [predict_human(s, HORIZONS[dataset]) for s in held_out]
        )
        results[dataset] = score(path, data, dataset, out / "runs" / "expert" / "scores" / dataset, references[dataset])
    return results


def score(predictions: Path, data: Path, dataset: str, out: Path, references: ReferenceCache) -> dict[str, Any]:
    """Every scorer the table needs on ``dataset`` (converted in ``data``): ``{scorer: aggregates}``; files under
    ``out/<scorer>``. ``references``: the PDM-Closed references planned on ``data``; a reference depends on the
    scene only, so PDMS and EPDMS, the expert and every model plan each sample's once (the slowest scoring step)."""
    results = {}
    for scorer in scorers_for(dataset):
        options = {"reference_cache": references} if scorer in REFERENCE_SCORERS else {}
        # allow_missing: only the held-out samples are predicted
        report = score_predictions(scorer, predictions, [data], out / scorer, allow_missing=True, **options)
        results[scorer] = report["aggregates"]
    return results


def smoke_config(training: Training, out: Path) -> Path:
    """The training's smoke twin with its ``quickstart/`` paths moved under ``out``, its run folder named after the
    training, as long as :data:`STEPS` says and, for a run without LEAD, no CARLA data; written to
    ``out/<name>.yaml``."""
    recipe = SMOKE / f"{training.recipe}.yaml"
    if not recipe.exists():
        raise FileNotFoundError(f"{recipe} not found: run the quickstart from a source checkout (pip install -e .)")
    config = yaml.safe_load(recipe.read_text().replace("quickstart/", f"{out.as_posix()}/"))
    config["trainer"]["default_root_dir"] = str(out / "runs" / training.name)
    config["trainer"]["max_epochs"], config["data"]["steps_per_epoch"] = STEPS[training.name]
    if training.without_lead:
        drop_carla(config)
    path = out / f"{training.name}.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def drop_carla(config: dict[str, Any]) -> None:
    """Take LEAD's synthetic data out of a LightningCLI config: the CARLA source, its supervision, its share of the
    batch and a CARLA pre-training to start from."""
    config["data"]["train"].pop("carla", None)
    config["model"].get("supervise", {}).pop("carla", None)
    config["model"].pop("init_from", None)
    anchors = config["data"]["schedule"]["anchors"]
    for shares in anchors.values():
        shares.pop("carla", None)


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


def train_and_score(
    training: Training, out: Path, console: Console, started: float, references: dict[str, ReferenceCache]
) -> dict[str, Any]:
    """Fit the training's config; predict and score the held-out logs with the weights before and after training."""
    config = smoke_config(training, out)
    run = out / "runs" / training.name
    shutil.rmtree(run, ignore_errors=True)  # a checkpoint left by an earlier quickstart would be predicted with
    results = {}
    if training.predicts:
        results[f"{training.name}/{UNTRAINED}"] = predict_and_score(config, run / UNTRAINED, out, None, references)
    with lightning_output_to(out / LIGHTNING_LOG):
        run_lightning_cli(["fit", "--config", str(config)])
    if training.predicts:
        checkpoint = run / "checkpoints" / "last.ckpt"
        results[f"{training.name}/{TRAINED}"] = predict_and_score(config, run / TRAINED, out, checkpoint, references)
    scored = ", scored before and after" if training.predicts else ""
    _stage(console, f"{training.name}: trained -> {run}{scored}", started)
    return results


def predict_and_score(
    config: Path, folder: Path, out: Path, checkpoint: Path | None, references: dict[str, ReferenceCache]
) -> dict[str, Any]:
    """Predict with ``config``'s model (``checkpoint``; None: its initial weights) into ``folder`` and score each
    dataset's predictions against that dataset alone."""
    args = ["predict", "--config", str(config), "--trainer.default_root_dir", str(folder)]
    with lightning_output_to(out / LIGHTNING_LOG):
        run_lightning_cli(args + (["--untrained"] if checkpoint is None else ["--ckpt_path", str(checkpoint)]))
    predictions = read_predictions(folder / "predictions.parquet")
    results = {}
    for dataset in EVAL_SPLITS:
        mine = [p for p in predictions if p.dataset == dataset]
        if mine:
            path = write_predictions(folder / f"{dataset}.parquet", mine)
            results[dataset] = score(
                path, out / "data" / dataset, dataset, folder / "scores" / dataset, references[dataset]
            )
    return results


def by_scorer(results: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """``{dataset: {scorer: aggregates}}`` -> ``{scorer: {dataset: aggregates}}``, the shape a table column reads
    with the key ``<dataset>.<aggregate>``."""
    scores: dict[str, dict[str, Any]] = {}
    for dataset, by_metric in results.items():
        for scorer, aggregates in by_metric.items():
            scores.setdefault(scorer, {})[dataset] = aggregates
    return scores


def table_rows() -> dict[str, dict[str, str]]:
    """Row name -> {dataset: the run id whose scores fill that dataset's columns}: the Expert, then every model after
    and before training (the paper's Table 4 trains one model per benchmark; a row here joins the two)."""
    rows = {EXPERT: dict.fromkeys(EVAL_SPLITS, "expert")}
    for model, runs in MODELS.items():
        for stage, name in ((TRAINED, model), (UNTRAINED, f"{model}, {BEFORE_TRAINING}")):
            rows[name] = {dataset: f"{run}/{stage}" for dataset, run in runs.items()}
    return rows


def table_spec() -> TableSpec:
    """Table 4's layout over the quickstart's rows: a column per metric and dataset, the paper's numbers from
    ``recipes/paper/table4.yaml`` beside the trained models and the Expert where it has them."""
    columns = tuple(
        Column(f"{LABELS[dataset]} {metric.column}", metric.scorer, f"{dataset}.{metric.aggregate}", metric.scale)
        for metric in METRICS
        for dataset in EVAL_SPLITS
        if metric.applies(dataset)
    )
    paper = load_spec("table4")
    rows = tuple(Row(name, name, paper_numbers(paper, name, columns)) for name in table_rows())
    notes = (
        "One seed, toy models, synthetic data: numbers show that training moves the scores, not what the models can "
        "do. Before training: the initial weights (LTFv6 + LEAD on WOD-E2E: its CARLA pre-training). PDMS and EPDMS "
        "in percent, ADE and FDE in metres; paper: the paper's Table 4 (real data)."
    )
    return TableSpec("Table 4 on synthetic data (held-out logs)", columns, rows, seeds=(0,), digits=2, notes=notes)


def paper_numbers(paper: TableSpec, name: str, columns: tuple[Column, ...]) -> tuple[float | None, ...]:
    """The paper's number for row ``name`` in each column: Table 4's row ``<name> (<dataset>)`` or ``<name>``,
    its column of the same metric."""
    numbers = []
    for column in columns:
        dataset = column.key.split(".")[0]
        row = next((r for r in paper.rows if r.name in (f"{name} ({LABELS[dataset]})", name)), None)
        index = next((i for i, c in enumerate(paper.columns) if c.metric == column.metric), None)
        numbers.append(None if row is None or index is None else row.paper[index])
    return tuple(numbers)


def table_runs(results: dict[str, Any], out: Path) -> list[Run]:
    """One run per table row, its scores gathered from the quickstart's runs as :func:`table_rows` says."""
    runs = []
    for name, sources in table_rows().items():
        scores = {dataset: results.get(run_id, {}).get(dataset, {}) for dataset, run_id in sources.items()}
        runs.append(Run(out / "runs", name, 0, by_scorer(scores)))
    return runs


def tables(spec: TableSpec, cells: list[list[Cell]]) -> list[Table]:
    """The console's view of :func:`table_spec`: one table per dataset with its metrics (the paper's number beside
    a metric where the paper has one) and short row names, so each fits an 80-column terminal; the files keep
    Table 4's single layout."""
    grids = []
    for dataset, split in EVAL_SPLITS.items():
        label = LABELS[dataset]
        columns = [i for i, column in enumerate(spec.columns) if column.key.startswith(f"{dataset}.")]
        papers = {i for i in columns if any(row.paper[i] is not None for row in spec.rows)}
        grid = Table(title=f"{label}: held-out {split} logs", title_justify="left")
        grid.add_column("model")
        for i in columns:
            grid.add_column(spec.columns[i].name.removeprefix(f"{label} "), justify="right")
            if i in papers:
                grid.add_column("paper", justify="right", style="dim")
        for row, row_cells in zip(spec.rows, cells, strict=True):
            numbers = []
            for i in columns:
                numbers.append(format_cell(row_cells[i], spec.digits))
                if i in papers:
                    numbers.append(PAPER_BLANK if row.paper[i] is None else f"{row.paper[i]:.{spec.digits}f}")
            grid.add_row(console_name(row.name), *numbers)
        grids.append(grid)
    return grids


def console_name(row: str) -> str:
    """A row's name on the console: a model's untrained row sits under its trained one as "before training"."""
    return f"  {BEFORE_TRAINING}" if row.endswith(f", {BEFORE_TRAINING}") else row
