"""The paper's infractions-per-100-km figure: one bar group per model, one bar per infraction type.

Drawn with OpenCV (already a dependency) rather than matplotlib, which the package does not otherwise need. A model
without results keeps its slot on the axis with a "no results" label, so a missing run is visible, not silently gone.
"""

from pathlib import Path

import cv2
import numpy as np

#: BGR colours, one per bar in a group (cycled).
PALETTE = ((180, 119, 31), (14, 127, 255), (44, 160, 44), (40, 39, 214), (189, 103, 148), (75, 86, 140))
FONT = cv2.FONT_HERSHEY_SIMPLEX
MARGIN_LEFT, MARGIN_RIGHT, MARGIN_TOP, MARGIN_BOTTOM = 70, 230, 50, 70
PLOT_HEIGHT, GROUP_WIDTH = 320, 160


def nice_ceiling(value: float) -> float:
    """The smallest 1, 2 or 5 times a power of ten at or above ``value`` (the y-axis top)."""
    if value <= 0:
        return 1.0
    power = 10 ** np.floor(np.log10(value))
    return float(next(m * power for m in (1, 2, 5, 10) if m * power >= value - 1e-12))


def _text(image: np.ndarray, text: str, origin: tuple[int, int], scale: float = 0.45) -> None:
    cv2.putText(image, text, origin, FONT, scale, (30, 30, 30), 1, cv2.LINE_AA)


def infraction_bars(
    groups: dict[str, dict[str, float] | None], infractions: list[str], out: str | Path, title: str = ""
) -> np.ndarray:
    """Draw ``{model: {infraction: per-100-km rate} | None}`` as grouped bars, write a PNG and return the image."""
    width = MARGIN_LEFT + GROUP_WIDTH * max(len(groups), 1) + MARGIN_RIGHT
    height = MARGIN_TOP + PLOT_HEIGHT + MARGIN_BOTTOM
    image = np.full((height, width, 3), 255, np.uint8)
    top = nice_ceiling(max((v for rates in groups.values() if rates for v in rates.values()), default=0.0))
    base_y, plot_right = MARGIN_TOP + PLOT_HEIGHT, width - MARGIN_RIGHT
    for tick in np.linspace(0.0, top, 5):
        y = round(base_y - tick / top * PLOT_HEIGHT)
        cv2.line(image, (MARGIN_LEFT, y), (plot_right, y), (225, 225, 225), 1)
        _text(image, f"{tick:g}", (8, y + 5))
    cv2.line(image, (MARGIN_LEFT, base_y), (plot_right, base_y), (30, 30, 30), 1)
    bar = (GROUP_WIDTH - 30) // max(len(infractions), 1)
    for g, (model, rates) in enumerate(groups.items()):
        x0 = MARGIN_LEFT + g * GROUP_WIDTH + 15
        _text(image, model[:22], (x0, base_y + 22))
        if rates is None:
            _text(image, "no results", (x0, base_y - 10))
            continue
        for i, name in enumerate(infractions):
            y = round(base_y - rates.get(name, 0.0) / top * PLOT_HEIGHT)
            cv2.rectangle(image, (x0 + i * bar, y), (x0 + (i + 1) * bar - 2, base_y), PALETTE[i % len(PALETTE)], -1)
    for i, name in enumerate(infractions):
        y = MARGIN_TOP + 10 + 22 * i
        cv2.rectangle(image, (plot_right + 15, y - 10), (plot_right + 29, y + 2), PALETTE[i % len(PALETTE)], -1)
        _text(image, name, (plot_right + 36, y))
    _text(image, title, (MARGIN_LEFT, 28), 0.55)
    _text(image, "infractions per 100 km", (MARGIN_LEFT, height - 18))
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), image):
        raise OSError(f"could not write the figure to {out}")
    return image
