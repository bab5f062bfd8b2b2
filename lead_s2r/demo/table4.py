"""The quickstart's Table 4: its rows (the Expert, each model after and before training), its columns (a metric per
dataset, :data:`METRICS`; a new metric is one line there), the paper's numbers beside them, and the console's view
of it: one table per dataset that fits 80 columns, then each camera model's camera reliance.

A "needs perception" metric scores the held-out scenes with pedestrians ahead only (:data:`PERCEPTION_TAGS`), where
the ego status cannot tell the driver to stop; the camera reliance (:mod:`lead_s2r.training.camera_reliance`) says
whether a camera model's plan reads its cameras at all. :func:`build_table4` makes the whole table here, from the
quickstart's scores to ``<out>/table`` (Table 4's single layout) and the console's view.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich import box
from rich.console import RenderableType
from rich.table import Table

from lead_s2r.files import write_text
from lead_s2r.report import tables as paper  # the paper's tables: collect and render
from lead_s2r.report.tables import Cell, Column, Row, Run, TableSpec, format_cell, format_paper, load_spec

#: dataset -> the held-out split every row is scored on, and its name in the table.
EVAL_SPLITS = {"navsim": "test", "wod_e2e": "val"}
LABELS = {"navsim": "NAVSIM", "wod_e2e": "WOD-E2E"}

#: dataset -> the tag of its scenes that need perception (:mod:`lead_s2r.synthetic.pedestrians_ahead`): NAVSIM's
#: from the generator's scene filter ``pedestrians_ahead.yaml`` (``tag_filters``), WOD-E2E's from its cluster file.
PERCEPTION_TAGS = {"navsim": "scene_filter:pedestrians_ahead", "wod_e2e": "cluster:Pedestrian"}

#: summary.json's key, beside a run's scores on a dataset, of its camera reliance
#: (:mod:`lead_s2r.training.camera_reliance`): ``{"mean_m": ..., "samples": ...}``.
CAMERA_RELIANCE = "camera_reliance"

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
    """One metric of the table: the aggregate ``aggregate`` of scorer ``scorer`` times ``scale``, on ``datasets`` (None:
    all), one column per dataset; ``needs_perception``: on the samples with the :data:`PERCEPTION_TAGS` tag only."""

    column: str
    scorer: str
    aggregate: str
    datasets: tuple[str, ...] | None = None
    scale: float = 1.0
    needs_perception: bool = False

    def applies(self, dataset: str) -> bool:
        return self.datasets is None or dataset in self.datasets

    def tag(self, dataset: str) -> str | None:  # of the samples scored on ``dataset`` (None: all of them)
        return PERCEPTION_TAGS[dataset] if self.needs_perception else None


METRICS = (
    Metric("PDMS", "pdms@navsim-1.1", "pdms", ("navsim",), scale=100.0),
    Metric("PDMS, needs perception", "pdms@navsim-1.1", "pdms", ("navsim",), scale=100.0, needs_perception=True),
    Metric("EPDMS", "epdms@navsim-2.2", "epdms", ("navsim",), scale=100.0),
    Metric("RFS", "rfs@wod-e2e-2025", "rfs", ("wod_e2e",)),
    Metric("RFS, needs perception", "rfs@wod-e2e-2025", "rfs", ("wod_e2e",), needs_perception=True),
    Metric("ADE", "ade", "ade"),
)


def build_table4(results: dict[str, Any], out: Path, seeds: tuple[int, ...]) -> list[RenderableType]:
    """Table 4 of the quickstart's ``results`` (``{run id: {dataset: {scores key: aggregates}}}``) over ``seeds``,
    written to ``out/table/table4.{md,tex,csv}``; returns the console's view (a table per dataset, notes, cameras)."""
    spec = table_spec(seeds)
    cells = paper.collect(spec, table_runs(results, out, seeds))
    for suffix, render in (("md", paper.to_markdown), ("tex", paper.to_latex), ("csv", paper.to_csv)):
        write_text(out / "table" / f"table4.{suffix}", render(spec, cells))
    return [*tables(spec, cells), spec.notes, camera_use(results, seeds)]


def scorings(dataset: str) -> list[tuple[str, str | None]]:
    """The (scorer, tag) pairs the table needs on ``dataset``, each once (tag None: every held-out sample)."""
    return list(dict.fromkeys((m.scorer, m.tag(dataset)) for m in METRICS if m.applies(dataset)))


def by_scorer(results: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """``{dataset: {scorer: aggregates}}`` -> ``{scorer: {dataset: aggregates}}``, the shape a table column reads
    with the key ``<dataset>.<aggregate>``."""
    scores: dict[str, dict[str, Any]] = {}
    for dataset, by_metric in results.items():
        for scorer, aggregates in by_metric.items():
            scores.setdefault(scorer, {})[dataset] = aggregates
    return scores


def table_rows() -> dict[str, dict[str, str]]:
    """Row name -> {dataset: the run id whose scores fill that dataset's columns, with ``{seed}`` for the seed}: the
    Expert (deterministic: the same scores for every seed), then every model after and before training (the paper's
    Table 4 trains one model per benchmark; a row here joins the two)."""
    rows = {EXPERT: dict.fromkeys(EVAL_SPLITS, "expert")}
    for model, runs in MODELS.items():
        for stage, name in ((TRAINED, model), (UNTRAINED, f"{model}, {BEFORE_TRAINING}")):
            rows[name] = {dataset: f"{run}/seed{{seed}}/{stage}" for dataset, run in runs.items()}
    return rows


def table_spec(seeds: tuple[int, ...]) -> TableSpec:
    """Table 4's layout over the quickstart's rows: a column per metric and dataset, the paper's numbers from
    ``recipes/paper/table4.yaml`` beside the trained models and the Expert where it has them."""
    columns = tuple(
        Column(f"{LABELS[d]} {m.column}", m.scorer, f"{d}.{m.aggregate}", m.scale, m.tag(d))
        for m in METRICS
        for d in EVAL_SPLITS
        if m.applies(d)
    )
    paper = load_spec("table4")
    rows = tuple(Row(name, name, paper_numbers(paper, name, columns)) for name in table_rows())
    notes = (
        f"Mean ± sample std over seeds {', '.join(map(str, seeds))}; toy models, synthetic data: the numbers show "
        "what training changes and how models rank on these worlds, not what the models can do on real data. Before "
        "training: the initial weights (LTFv6 + LEAD on WOD-E2E: its CARLA pre-training). PDMS and EPDMS in percent, "
        "ADE in metres; paper: the paper's real-data table (its NAVSIM v2 Expert is a privileged planner). Needs "
        "perception: the same metric on the held-out scenes with pedestrians in the lane ahead, which only the cameras "
        "show (a third of the logs; the paper has no such column)."
    )
    return TableSpec("Table 4 on synthetic data (held-out logs)", columns, rows, seeds=seeds, digits=2, notes=notes)


def paper_numbers(paper: TableSpec, name: str, columns: tuple[Column, ...]) -> tuple[float | str | None, ...]:
    """The paper's number for row ``name`` in each column: Table 4's row ``<name> (<dataset>)`` (``Expert (logged)``
    -> ``Expert (NAVSIM)``) or ``<name>``, its column of the same metric."""
    numbers = []
    for column in columns:
        dataset = column.key.split(".")[0]
        names = (f"{name} ({LABELS[dataset]})", f"{name.split(' (')[0]} ({LABELS[dataset]})", name)
        row = next((r for r in paper.rows if r.name in names), None)
        index = next((i for i, c in enumerate(paper.columns) if c.scores == column.scores), None)
        numbers.append(None if row is None or index is None else row.paper[index])
    return tuple(numbers)


def table_runs(results: dict[str, Any], out: Path, seeds: tuple[int, ...]) -> list[Run]:
    """One run per table row, its scores gathered from the quickstart's runs as :func:`table_rows` says."""
    runs = []
    for name, sources in table_rows().items():
        for seed in seeds:
            ids = {dataset: run_id.format(seed=seed) for dataset, run_id in sources.items()}
            scores = {dataset: results.get(run_id, {}).get(dataset, {}) for dataset, run_id in ids.items()}
            if any(scores.values()):
                runs.append(Run(out / "runs", name, seed, by_scorer(scores)))
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
        # no padding, no edges: the box's one space between columns, so NAVSIM's six number columns fit 80 columns
        title = f"{label}: held-out {split} logs"
        grid = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD, padding=0, show_edge=False)
        grid.add_column("model")
        for i in columns:
            header = spec.columns[i].name.removeprefix(f"{label} ").replace(" perception", "\nperception")
            grid.add_column(header, justify="right")
            if i in papers:
                grid.add_column("paper", justify="right", style="dim")
        for row, row_cells in zip(spec.rows, cells, strict=True):
            numbers = []
            for i in columns:
                numbers.append(format_cell(row_cells[i], spec.digits))
                if i in papers:
                    numbers.append(format_paper(row.paper[i], spec.digits))
            grid.add_row(console_name(row.name), *numbers)
        grids.append(grid)
    return grids


def camera_use(results: dict[str, Any], seeds: tuple[int, ...]) -> str:
    """What the console says of each camera model's camera reliance on each dataset: mean ± std over the seeds after
    training, then before, so a row that scores like the Ego MLP shows whether its plan ignores its cameras."""
    lines = [
        "Camera reliance (m): how far the held-out waypoints move, on average, when every sample is given another "
        "sample's camera images (0: the plan ignores the cameras; docs/training.md, \"Does LTFv6 look at its "
        'cameras?"):'
    ]
    for dataset in EVAL_SPLITS:
        for model, runs in MODELS.items():
            cells = [
                Cell(tuple(shifts), ())
                for stage in (TRAINED, UNTRAINED)
                if (shifts := camera_shifts(results, runs[dataset], stage, dataset, seeds))
            ]
            if len(cells) == 2:  # one line each, to fit 80 columns
                trained, untrained = (format_cell(cell, 2) for cell in cells)
                lines.append(f"  {LABELS[dataset]}, {model}: {trained} ({UNTRAINED} {untrained})")
    return "\n".join(lines)


def camera_shifts(results: dict[str, Any], run: str, stage: str, dataset: str, seeds: tuple[int, ...]) -> list[float]:
    """The camera reliance of ``run`` at ``stage`` on ``dataset``, one per seed that measured it."""
    found = (results.get(f"{run}/seed{seed}/{stage}", {}).get(dataset, {}).get(CAMERA_RELIANCE) for seed in seeds)
    return [entry["mean_m"] for entry in found if entry]


def console_name(row: str) -> str:
    """A row's name on the console: a model's untrained row sits under its trained one as "untrained", the Expert
    without "(logged)" (short, so NAVSIM's six number columns fit 80 columns; the notes say what the Expert is)."""
    if row == EXPERT:
        return EXPERT.split(" (")[0]
    return f"  {UNTRAINED}" if row.endswith(f", {BEFORE_TRAINING}") else row
