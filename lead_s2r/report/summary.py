"""The report's summary: per metric and dataset the aggregates of scores.json and every sub-score, histograms of the
per-sample sub-scores, and the loss / validation curves of the run's Lightning CSV logs.

Numbers are printed rounded but carry their exact value (``data-value``, Python's ``repr``), so a test (or a reader
with the page source) can check them against scores.json without rounding games.
"""

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from lead_s2r.fields import is_number
from lead_s2r.report.bev import save_figure
from lead_s2r.report.run_outputs import MetricScores
from lead_s2r.report.sample_page import is_score

HISTOGRAM_COLUMNS = 4
#: at most this many training curves are drawn (the first ones of the logs, losses before the rest)
MAX_CURVES = 12


def flat_numbers(aggregates: dict[str, Any], prefix: str = "") -> list[tuple[str, float]]:
    """``(dotted key, value)`` of every number in (nested) aggregates; booleans and nulls are left out."""
    numbers = []
    for name, value in aggregates.items():
        key = f"{prefix}{name}"
        if isinstance(value, dict):
            numbers += flat_numbers(value, f"{key}.")
        elif is_number(value, finite=False):
            numbers.append((key, float(value)))
    return numbers


def score_columns(scores: MetricScores) -> dict[str, np.ndarray]:
    """The per-sample values of every numeric sub-score column of a scores table (step indices left out)."""
    columns: dict[str, list[float]] = {}
    for row in scores.rows.values():
        for name, value in row.items():
            if is_score(name, value):
                columns.setdefault(name, []).append(np.nan if value is None else float(value))
    return {name: np.asarray(values) for name, values in columns.items()}


def histograms(scores: MetricScores, out: Path) -> bool:
    """One small histogram per sub-score column, in a grid, written to ``out``; False when there is nothing."""
    columns = {name: values[np.isfinite(values)] for name, values in score_columns(scores).items()}
    columns = {name: values for name, values in columns.items() if len(values)}
    if not columns:
        return False
    rows = -(-len(columns) // HISTOGRAM_COLUMNS)
    figure = Figure(figsize=(3.0 * HISTOGRAM_COLUMNS, 2.2 * rows), dpi=80)
    for index, (name, values) in enumerate(columns.items()):
        axes = figure.add_subplot(rows, HISTOGRAM_COLUMNS, index + 1)
        counts, edges = np.histogram(values, bins=20)
        axes.stairs(counts, edges, fill=True, color="#4c72b0")  # one patch, not 20 bars: a tenth of the report's time
        axes.set_title(name, fontsize=8)
        axes.tick_params(labelsize=7)
        axes.ticklabel_format(useOffset=False)
    figure.suptitle(scores.label, fontsize=10)
    # fixed margins: tight_layout measures every tick label and cost most of a report's time
    figure.subplots_adjust(left=0.05, right=0.98, bottom=0.35 / rows, top=1 - 0.45 / rows, wspace=0.3, hspace=0.8)
    save_figure(figure, out)
    return True


def curves_figure(curves: dict[str, list[tuple[float, float]]], out: Path) -> bool:
    """Training curves (loss columns first) against the optimizer step; False when the run has no logs."""
    names = sorted(curves, key=lambda name: ("loss" not in name, name))[:MAX_CURVES]
    if not names:
        return False
    figure = Figure(figsize=(9, 4), dpi=80)
    axes = figure.add_subplot(1, 1, 1)
    for name in names:
        points = np.asarray(curves[name])
        axes.plot(points[:, 0], points[:, 1], "o-" if len(points) < 20 else "-", markersize=3, label=name)
    axes.set_xlabel("optimizer step")
    axes.legend(fontsize=7, ncol=2)
    figure.subplots_adjust(left=0.07, right=0.98, bottom=0.12, top=0.95)
    save_figure(figure, out)
    return True
