"""The paper's infractions-per-100-km figure: one bar group per model, one bar per infraction type.

A model without results keeps its slot on the axis with a "no results" label, so a missing run is visible.
"""

import textwrap
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lead_s2r.report.bev import save_figure


def infraction_bars(
    groups: dict[str, dict[str, float] | None], infractions: list[str], out: str | Path, title: str = ""
) -> Figure:
    """Draw ``{model: {infraction: per-100-km rate} | None}`` as grouped bars, write a PNG and return the figure."""
    figure = Figure(figsize=(1.6 * max(len(groups), 1) + 3.0, 4.4), dpi=100, layout="constrained")
    axes = figure.add_subplot()
    slots, width = np.arange(len(groups)), 0.8 / max(len(infractions), 1)
    for i, name in enumerate(infractions):
        rates = [(group or {}).get(name, 0.0) for group in groups.values()]
        axes.bar(slots + (i - (len(infractions) - 1) / 2) * width, rates, width, label=name)
    for slot, group in zip(slots, groups.values(), strict=True):
        if group is None:
            axes.text(slot, 0.0, "no results", ha="center", va="bottom", fontsize=8)
    axes.set_xticks(slots, [textwrap.fill(model, 22) for model in groups], fontsize=8)
    axes.set_ylabel("infractions per 100 km")
    axes.set_title(title, fontsize=10)
    figure.legend(loc="outside right upper", fontsize=8)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    save_figure(figure, out)
    return figure
