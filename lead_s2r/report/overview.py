"""The index of many runs: per family, every model's headline scores as mean ± std over its seeds.

The numbers are :mod:`lead_s2r.report.tables`'s (the spec, :func:`~lead_s2r.report.tables.collect`,
:func:`~lead_s2r.report.tables.format_cell`): a table spec made from the runs found, one row per run id and one column
per scores.json metric (and tagged subset) with its headline aggregate, so the index reads exactly as
``lead-s2r table`` would print those columns.
"""

from dataclasses import dataclass
from pathlib import Path

from lead_s2r.report.run_outputs import HEADLINES
from lead_s2r.report.tables import Column, Row, Run, TableSpec, collect, format_cell

#: digits of the index's means and stds
DIGITS = 3


@dataclass(frozen=True)
class FamilyTable:
    """One family's models (``navsim / ltfv6``) with their seeds and a ``mean ± std`` text per column."""

    family: str
    columns: list[str]
    rows: list[tuple[str, list[int], list[str]]]


def headline_columns(runs: list[Run]) -> list[Column]:
    """One column per (metric, tag) the runs scored, each with its family's headline aggregate (``pdms``); scores
    before errors (PDMS before ADE), as the comparison orders them."""
    columns = {}
    for run in runs:
        for key, aggregates in run.scores.items():
            metric, _, tag = key.partition("#")
            family = metric.split("@")[0]
            if family in HEADLINES and family in aggregates:
                name = metric if not tag else f"{metric} on {tag}"
                columns.setdefault(key, Column(name, metric, family, tag=tag or None))
    return sorted(columns.values(), key=lambda column: not HEADLINES[column.metric.split("@")[0]][1])


def headline_tables(runs: list[Run]) -> list[FamilyTable]:
    """Per family (``runs/<family>/...``), a row per run id with its seeds and headline cells."""
    tables = []
    families: dict[str, list[Run]] = {}
    for run in runs:
        families.setdefault(Path(run.run_id).parent.name, []).append(run)
    for family, members in families.items():
        columns = headline_columns(members)
        ids = list(dict.fromkeys(run.run_id for run in members))
        seeds = {run_id: sorted(run.seed for run in members if run.run_id == run_id) for run_id in ids}
        rows = tuple(Row(run_id, run_id, (None,) * len(columns), tuple(seeds[run_id])) for run_id in ids)
        cells = collect(TableSpec(family, tuple(columns), rows), members)
        texts = [[format_cell(cell, DIGITS) for cell in row_cells] for row_cells in cells]
        names = [" / ".join(Path(run_id).parts[-2:]) for run_id in ids]
        listed = list(zip(names, [seeds[run_id] for run_id in ids], texts, strict=True))
        tables.append(FamilyTable(family, [column.name for column in columns], listed))
    return tables
