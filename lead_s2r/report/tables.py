"""The paper's tables from run results: mean ± std over seeds beside the paper's numbers, in markdown, LaTeX and CSV.

A table spec (``recipes/paper/*.yaml``) names columns (a scorer's metric and an aggregate key of its
``scores.json``) and rows (a run id and the paper's numbers). Runs are found, not listed: a run is laid out as
``runs/<family>/<name>/seed<k>/`` (config, checkpoints, predictions, and any number of ``scores.json`` below it from
``lead-s2r score`` and ``lead-s2r carla-metrics``), so ``--runs 'runs/*/*/seed*'`` is enough; the folder gives the run
id (``runs/<family>/<name>``) and the seed. A run folder named otherwise takes both from the ``config.yaml`` that
``lead-s2r fit`` saved (``seed_everything``; ``trainer.default_root_dir`` minus a trailing ``seed<k>``). A row
matches a run whose id ends with the row's ``run`` path. Glob patterns that match nothing are left out, so one
command serves any subset of families.

The trap: a cell averaged over fewer seeds than the spec asks for looks like a result. Such cells carry a ``*`` and
the seeds that are missing are listed under the table; a cell with no run at all reads ``missing``.
"""

import csv
import glob
import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from lead_s2r.errors import UserError
from lead_s2r.fields import check_fields, fits, is_number
from lead_s2r.files import write_text
from lead_s2r.scoring.carla_leaderboard import INFRACTIONS
from lead_s2r.scoring.scores_file import SCORES_JSON, ScoresFile, scores_folders

#: The table specs of the paper (Tables 1-5), next to the recipes they read.
PAPER_SPECS = Path(__file__).resolve().parents[2] / "recipes" / "paper"
SEED_FOLDER = re.compile(r"^seed[_-]?(\d+)$")
MISSING = "missing"


class TableError(UserError, ValueError):
    """A spec or run directory that cannot make a table; the message names the file and field."""


@dataclass(frozen=True)
class Column:
    """One reported number: ``key`` (dots reach into nested aggregates) of the ``scores.json`` whose ``metric`` matches
    and that scored the samples with ``tag`` (``lead-s2r score --tag``; None: scored without one), times ``scale``."""

    name: str
    metric: str
    key: str
    scale: float = 1.0
    tag: str | None = None

    @property
    def scores(self) -> str:
        """The key of this column's scores in :attr:`Run.scores`."""
        return scores_key(self.metric, self.tag)


def scores_key(metric: str, tag: str | None) -> str:
    """How a run's scores of ``metric`` on the samples with ``tag`` are filed: ``pdms@navsim-1.1`` for all samples,
    ``pdms@navsim-1.1#scene_filter:pedestrians_ahead`` for a tagged subset."""
    return metric if tag is None else f"{metric}#{tag}"


@dataclass(frozen=True)
class Row:
    """One model: the run id it is trained under and the paper's number per column (None: not reported; a string is
    printed as the paper prints it, e.g. ``"5.24"`` or ``"83.56 ± 0.32"``; a float with the table's digits)."""

    name: str
    run: str | None
    paper: tuple[float | str | None, ...]
    #: the seeds this row averages over when not the table's (the Expert: one replay, ``[0]``)
    seeds: tuple[int, ...] | None = None


@dataclass(frozen=True)
class TableSpec:
    title: str
    columns: tuple[Column, ...]
    rows: tuple[Row, ...]
    seeds: tuple[int, ...] = (0, 1, 2)
    digits: int = 2
    notes: str = ""
    #: optional bar chart of infractions per 100 km: {"metric": ..., "infractions": [...]}
    figure: dict[str, Any] | None = None


def spec_path(spec: str | Path) -> Path:
    """A spec file, or the name of one shipped in ``recipes/paper`` (``table4``) of this source checkout."""
    path = Path(spec)
    if not path.exists() and path.parent == Path(".") and (PAPER_SPECS / f"{path.stem}.yaml").exists():
        return PAPER_SPECS / f"{path.stem}.yaml"
    return path


#: The JSON/YAML type of each field of a spec, a column and a row (``bool`` is no number here).
SPEC_FIELDS = {"title": str, "columns": list, "rows": list, "seeds": list[int], "digits": int, "notes": str}
COLUMN_FIELDS = {"name": str, "metric": str, "key": str, "scale": int | float, "tag": str | None}
ROW_FIELDS = {"name": str, "run": str | None, "paper": list | None, "seeds": list[int]}
FIGURE_FIELDS = {"metric": str, "infractions": list[str]}


def _typed(path: Path, where: str, mapping: Any, kinds: dict[str, Any]) -> dict[str, Any]:
    """``mapping`` when it is a mapping whose fields have the types ``kinds`` gives."""
    return check_fields(mapping, kinds, str(path), TableError, "see docs/reproducing.md for the spec's fields", where)


def load_spec(path: str | Path) -> TableSpec:
    """Read and check a table spec (a path or a shipped name, see :func:`spec_path`); errors name file and field."""
    path = spec_path(path)
    try:
        raw = yaml.safe_load(path.read_bytes())
    except (OSError, yaml.YAMLError) as err:  # YAMLError covers bytes that are not UTF-8
        raise TableError(f"{path}: cannot read table spec: {err}") from None
    _typed(path, "the spec", raw, SPEC_FIELDS)
    try:
        columns = tuple(
            Column(**_typed(path, f"columns[{i}]", column, COLUMN_FIELDS)) for i, column in enumerate(raw["columns"])
        )
        rows = tuple(_row(path, i, row, len(columns)) for i, row in enumerate(raw["rows"]))
        spec = TableSpec(
            title=raw["title"],
            columns=columns,
            rows=rows,
            seeds=tuple(raw.get("seeds", (0, 1, 2))),
            digits=raw.get("digits", 2),
            notes=raw.get("notes", ""),
            figure=raw.get("figure"),
        )
    except (KeyError, TypeError) as err:
        raise TableError(f"{path}: bad table spec ({type(err).__name__}: {err}); see docs/reproducing.md") from None
    _check_figure(path, spec.figure)
    for row in spec.rows:
        if not all(p is None or isinstance(p, str) or is_number(p, finite=False) for p in row.paper):
            raise TableError(f"{path}: row {row.name!r}: paper numbers are numbers, strings as printed, or null")
        if len(row.paper) != len(spec.columns):
            raise TableError(
                f"{path}: row {row.name!r} lists {len(row.paper)} paper numbers for {len(columns)} columns"
            )
    return spec


def _row(path: Path, index: int, row: Any, columns: int) -> Row:
    row = _typed(path, f"rows[{index}]", row, ROW_FIELDS)
    paper = row.get("paper")
    seeds = row.get("seeds")
    return Row(
        row["name"],
        row.get("run"),
        (None,) * columns if paper is None else tuple(paper),
        None if seeds is None else tuple(seeds),
    )


def _check_figure(path: Path, figure: Any) -> None:
    if figure is None:
        return
    figure = _typed(path, "figure", figure, FIGURE_FIELDS)
    infractions = figure.get("infractions")
    if "metric" not in figure or not infractions:
        raise TableError(f"{path}: figure needs 'metric' (a carla-metrics metric) and a list of 'infractions'")
    unknown = sorted(set(infractions) - set(INFRACTIONS))
    if unknown:
        raise TableError(
            f"{path}: figure.infractions: unknown {unknown}; the leaderboard's names are {list(INFRACTIONS)}"
        )


@dataclass
class Run:
    """One trained seed: its id, seed and the aggregates of every scores.json below it, by :func:`scores_key`."""

    path: Path
    run_id: str
    seed: int
    scores: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: the scores.json each entry of ``scores`` was read from, to name it in an error
    sources: dict[str, Path] = field(default_factory=dict)


def _saved_config(config_path: Path) -> tuple[dict[str, Any], int]:
    """A LightningCLI ``config.yaml`` and its seed."""
    try:
        config = yaml.safe_load(config_path.read_bytes()) or {}
    except (OSError, yaml.YAMLError) as err:
        raise TableError(f"{config_path}: cannot read the saved config: {err}") from None
    if not isinstance(config, dict):
        raise TableError(f"{config_path}: holds {config!r}, not the mapping lead-s2r fit saves")
    seed = config.get("seed_everything")
    if not fits(seed, int):
        raise TableError(f"{config_path}: seed_everything is {seed!r}; train with a fixed integer seed")
    return config, seed


def run_identity(config_path: Path) -> tuple[str, int]:
    """(run id, seed) from a LightningCLI ``config.yaml``."""
    config, seed = _saved_config(config_path)
    trainer = config.get("trainer") or {}
    root = trainer.get("default_root_dir") if isinstance(trainer, dict) else None
    if not root or not isinstance(root, str):
        raise TableError(f"{config_path}: trainer.default_root_dir is not set; recipes name the run there")
    path = Path(root)
    return str(path.parent if SEED_FOLDER.match(path.name) else path), seed


def folder_identity(path: Path) -> tuple[str, int] | None:
    """(run id, seed) of a run folder laid out as ``.../<family>/<name>/seed<k>``; None for another name."""
    match = SEED_FOLDER.match(path.name)
    return None if match is None else (str(path.parent), int(match.group(1)))


def load_run(path: Path) -> Run:
    """A run directory: its identity (from its folder, else from the config ``fit`` saved) and every
    ``scores.json`` below it. A fit config whose seed is not the folder's is an error: it trained another seed."""
    configs = list(path.rglob("config.yaml"))  # fit saves config.yaml; predict, validate, test their own names
    identity = folder_identity(path)
    for config in configs if identity else []:
        seed = _saved_config(config)[1]
        if seed != identity[1]:
            raise TableError(
                f"{config}: seed_everything is {seed} in the folder of seed {identity[1]}; "
                f"train with --seed_everything {identity[1]} or move the run to seed{seed}/"
            )
    if identity is None:
        if not configs:
            raise TableError(
                f"{path}: not a run folder: neither named seed<k> (runs/<family>/<name>/seed<k>) nor holding the "
                "config.yaml that lead-s2r fit saves"
            )
        identities = {run_identity(config) for config in configs}
        if len(identities) > 1:
            raise TableError(f"{path}: its config.yaml files disagree on (run id, seed): {sorted(identities)}")
        identity = identities.pop()
    run = Run(path, *identity)
    for folder in scores_folders(path):
        scores = ScoresFile.read(folder, rows=False, error=TableError)
        key = scores_key(scores.report["metric"], scores.report.get("tag"))
        if key in run.scores:
            raise TableError(f"{path}: two scores.json for metric {key!r} (one is {folder / SCORES_JSON}); keep one")
        run.scores[key] = scores.report.get("aggregates", {})
        run.sources[key] = folder / SCORES_JSON
    return run


def find_runs(patterns: list[str]) -> list[Run]:
    """Run directories from paths or glob patterns (the shell may have expanded them). A pattern that matches nothing is
    left out (a family not trained yet); a plain path that does not exist is an error, as is finding no run at all."""
    paths = [Path(p) for pattern in patterns for p in (sorted(glob.glob(pattern)) or _literal(pattern))]
    missing = [str(p) for p in paths if not p.is_dir()]
    if missing:
        raise TableError(f"--runs: no such directory {missing[0]}")
    if not paths:
        raise TableError(f"--runs: no run folder matches {' '.join(patterns)} (runs are laid out as runs/*/*/seed*)")
    return [load_run(path) for path in paths]


def _literal(pattern: str) -> list[str]:
    return [] if glob.has_magic(pattern) else [pattern]


def _lookup(run: Run, column: Column) -> float | None:
    """The column's number in the run's scores; None where the run has no such scores or key, or where the value is
    null (a metric undefined on the data). Anything else there is no result: an error naming the scores.json."""
    where = run.sources.get(column.scores, run.path)
    value: Any = run.scores.get(column.scores, {})
    parts = column.key.split(".")
    for depth, part in enumerate(parts):
        if value is not None and not isinstance(value, dict):
            raise TableError(f"{where}: aggregates.{'.'.join(parts[:depth])} is {value!r}, not a mapping of {part!r}")
        if value is None or part not in value:
            return None
        value = value[part]
    if value is None:
        return None
    if not is_number(value, finite=False):
        raise TableError(f"{where}: aggregates.{column.key} is {value!r}, not a number")
    return float(value)


@dataclass(frozen=True)
class Cell:
    """Mean and sample std (n - 1) over the seeds found; ``missing_seeds`` of those the spec asks for."""

    values: tuple[float, ...]
    missing_seeds: tuple[int, ...]

    @property
    def mean(self) -> float | None:
        return sum(self.values) / len(self.values) if self.values else None

    @property
    def std(self) -> float | None:
        if len(self.values) < 2:
            return None
        mean = self.mean
        return math.sqrt(sum((v - mean) ** 2 for v in self.values) / (len(self.values) - 1))


def matches(run: Run, row: Row) -> bool:
    """Whether ``run`` is one of ``row``'s seeds: its id ends with the row's run path (whole components)."""
    return row.run is not None and id_ends_with(run.run_id, row.run)


def id_ends_with(run_id: str, wanted: str) -> bool:
    """Whether run id ``runs/navsim/ltfv6`` ends with the path ``wanted`` (``ltfv6``, ``navsim/ltfv6``), whole parts."""
    parts = Path(wanted).parts
    return Path(run_id).parts[-len(parts) :] == parts


def collect(spec: TableSpec, runs: list[Run]) -> list[list[Cell]]:
    """One cell per row and column; a run seen twice for the same row and seed is an error."""
    table = []
    for row in spec.rows:
        by_seed: dict[int, Run] = {}
        for run in (run for run in runs if matches(run, row)):
            if run.seed in by_seed:
                raise TableError(
                    f"row {row.name!r}: seed {run.seed} found twice ({by_seed[run.seed].path}, {run.path})"
                )
            by_seed[run.seed] = run
        cells = []
        for column in spec.columns:
            values, missing = [], []
            for seed in row.seeds or spec.seeds:
                run = by_seed.get(seed)
                value = None if run is None else _lookup(run, column)
                if value is None:
                    missing.append(seed)
                else:
                    values.append(value * column.scale)
            cells.append(Cell(tuple(values), tuple(missing)))
        table.append(cells)
    return table


def format_cell(cell: Cell, digits: int) -> str:
    """``mean ± std``, ``*`` when seeds are missing, ``missing`` when none was found."""
    if cell.mean is None:
        return MISSING
    text = f"{cell.mean:.{digits}f}"
    if cell.std is not None:
        text += f" ± {cell.std:.{digits}f}"
    return text + ("*" if cell.missing_seeds else "")


def format_paper(value: float | str | None, digits: int) -> str:
    """The paper's number: as printed when the spec gives a string, ``–`` where the paper has none."""
    if value is None:
        return "–"
    return value if isinstance(value, str) else f"{value:.{digits}f}"


def layout(spec: TableSpec, cells: list[list[Cell]]) -> tuple[list[str], list[list[str]]]:
    """The header and the rows of text every format renders: a model column, then ours and the paper's per column."""
    header = ["model"] + [f"{c.name} {who}" for c in spec.columns for who in ("(ours)", "(paper)")]
    body = [
        [row.name]
        + [
            t
            for cell, p in zip(row_cells, row.paper, strict=True)
            for t in (format_cell(cell, spec.digits), format_paper(p, spec.digits))
        ]
        for row, row_cells in zip(spec.rows, cells, strict=True)
    ]
    return header, body


def to_markdown(spec: TableSpec, cells: list[list[Cell]]) -> str:
    header, body = layout(spec, cells)
    lines = [f"**{spec.title}**", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in body]
    extra = [
        f"* {row.name} / {column.name}: seeds {list(cell.missing_seeds)} missing"
        for row, row_cells in zip(spec.rows, cells, strict=True)
        for column, cell in zip(spec.columns, row_cells, strict=True)
        if cell.missing_seeds and cell.values
    ]
    extra += [spec.notes.strip()] if spec.notes.strip() else []
    return "\n".join(lines + (["", *extra] if extra else [])) + "\n"


def _latex_escape(text: str) -> str:
    for char, escaped in (("\\", r"\textbackslash{}"), ("&", r"\&"), ("%", r"\%"), ("_", r"\_"), ("#", r"\#")):
        text = text.replace(char, escaped)
    return text.replace("±", r"$\pm$").replace("–", "--")


def to_latex(spec: TableSpec, cells: list[list[Cell]]) -> str:
    header, body = layout(spec, cells)
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        r"\begin{tabular}{l" + "rr" * len(spec.columns) + "}",
        r"\toprule",
        " & ".join(_latex_escape(h) for h in header) + r" \\",
        r"\midrule",
    ]
    lines += [" & ".join(_latex_escape(t) for t in row) + r" \\" for row in body]
    lines += [r"\bottomrule", r"\end{tabular}", r"\caption{" + _latex_escape(spec.title) + "}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def to_csv(spec: TableSpec, cells: list[list[Cell]]) -> str:
    """Long format: one line per cell with mean, std, seeds found and missing, and the paper's number."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["model", "column", "metric", "key", "mean", "std", "n", "missing_seeds", "paper"])
    for row, row_cells in zip(spec.rows, cells, strict=True):
        for column, cell, paper in zip(spec.columns, row_cells, row.paper, strict=True):
            missing = " ".join(str(s) for s in cell.missing_seeds)
            fields = (cell.mean, cell.std, len(cell.values), missing, paper)
            writer.writerow(
                [row.name, column.name, column.metric, column.key, *["" if f is None else f for f in fields]]
            )
    return out.getvalue()


def build_table(spec_name: str | Path, run_patterns: list[str], out: str | Path | None = None) -> str:
    """The body of ``lead-s2r table``: the markdown table; with ``out``, also ``<spec>.md/.tex/.csv`` (and
    ``<spec>.png`` when the spec asks for the infractions figure)."""
    spec = load_spec(spec_name)
    runs = find_runs(run_patterns)
    cells = collect(spec, runs)
    markdown = to_markdown(spec, cells)
    if out is not None:
        out = Path(out)
        stem = spec_path(spec_name).stem
        write_text(out / f"{stem}.md", markdown)
        write_text(out / f"{stem}.tex", to_latex(spec, cells))
        write_text(out / f"{stem}.csv", to_csv(spec, cells))
        if spec.figure is not None:
            from lead_s2r.report.figures import infraction_bars

            groups = {row.name: mean_infractions(spec, row, runs) for row in spec.rows}
            infraction_bars(groups, list(spec.figure["infractions"]), out / f"{stem}.png", spec.title)
    return markdown


def mean_infractions(spec: TableSpec, row: Row, runs: list[Run]) -> dict[str, float] | None:
    """Per-100-km rate of each figure infraction, averaged over the row's seeds (None: no run found)."""
    metric, names = spec.figure["metric"], spec.figure["infractions"]
    rates = [
        {name: _lookup(run, Column(name, metric, f"infractions_per_100km.{name}")) or 0.0 for name in names}
        for run in runs
        if matches(run, row) and metric in run.scores
    ]
    if not rates:
        return None
    return {name: sum(r[name] for r in rates) / len(rates) for name in names}
