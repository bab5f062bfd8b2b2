"""Loss curves of one run: every loss term Lightning's CSV logger wrote, training and validation, one panel per term.

A user who sees only a final score cannot tell a model that learned slowly from one that did not learn at all; the
curves show it. Read from ``metrics.csv`` (one row per logged step, a column per metric, blank where a metric was not
logged that step), so they work for any run with Lightning's default logger.
"""

import math
from pathlib import Path

from matplotlib.figure import Figure

from lead_s2r.errors import UserError
from lead_s2r.report.training_log import TrainingLog

#: Path components of logged metrics that are not loss terms (validation displacement errors, batch sizes).
NOT_LOSSES = frozenset({"ade", "fde", "batch_size"})


def read_curves(metrics_csv: Path) -> dict[str, list[tuple[int, float]]]:
    """``{metric: [(step, value), ...]}`` for every ``train/`` and ``val/`` loss term in ``metrics_csv`` (read by
    :class:`~lead_s2r.report.training_log.TrainingLog`, which names a damaged file)."""
    curves: dict[str, list[tuple[int, float]]] = {}
    for name, step, value in TrainingLog(metrics_csv).read():
        if name.startswith(("train/", "val/")) and not NOT_LOSSES & set(name.split("/")):
            curves.setdefault(name.removesuffix("_epoch"), []).append((int(step), value))
    return {name: points for name, points in curves.items() if not name.endswith("_step")}


def plot_loss_curves(metrics_csv: Path, out: Path, title: str = "") -> Path:
    """Draw every loss term of ``metrics_csv`` (training per step, validation per epoch) into the PNG ``out``."""
    curves = read_curves(metrics_csv)
    terms = sorted({name.split("/", 1)[1] for name in curves})
    if not terms:
        raise UserError(f"{metrics_csv}: no train/ or val/ loss terms logged")
    columns = min(3, len(terms))
    rows = math.ceil(len(terms) / columns)
    figure = Figure(figsize=(4 * columns, 3 * rows))
    axes = figure.subplots(rows, columns, squeeze=False)
    for ax, term in zip(axes.flat, terms, strict=False):
        for stage, style in (("train", "-"), ("val", "o-")):
            points = curves.get(f"{stage}/{term}")
            if points:
                steps, values = zip(*points, strict=True)
                ax.plot(steps, values, style, label=stage, markersize=3)
        ax.set_title(term, fontsize=9)
        ax.set_xlabel("optimizer step", fontsize=8)
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[len(terms) :]:
        ax.axis("off")
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=80)
    return out
