"""Do two convex outlines share a point (GEOS ``intersects``)? The separating-axis test in numpy for the many pairs
NC and TTC check (ego box against agent box, ego front edge against agent box), GEOS for the few that floats cannot
decide.

Two convex outlines are disjoint exactly when the projections on one of their edge normals leave a gap (a box has
two edge directions, a segment one). Computed
in floats, a projection is off by far less than :data:`MARGIN`, so a gap wider than it on some axis means disjoint
and an overlap deeper than it on every axis means intersecting, whatever the rounding; a pair within the margin
(touching, or degenerate with a zero-length edge) goes to ``shapely.intersects`` on the same corners, which is what
NAVSIM's STRtree query decides. The answer is GEOS's for every pair, and a pair's answer does not depend on the pairs
beside it.
"""

from collections.abc import Callable
from dataclasses import dataclass
from functools import reduce

import numpy as np

#: [m] along a unit axis: separations or overlaps within this are left to GEOS (float error is ~1e-13 m at 1 km)
MARGIN = 1e-7


def _unit_normals(outline: np.ndarray) -> np.ndarray:
    """``(P, E, 2)`` unit normals of the edges of outlines ``(P, K, 2)`` that can separate: a box's first two edges
    (its other two are parallel to them, to rounding far below :data:`MARGIN`), a segment's (K = 2) one edge."""
    edges = outline[:, 1:3] - outline[:, :2] if outline.shape[1] > 2 else outline[:, 1:] - outline[:, :1]
    length = np.hypot(edges[..., 0], edges[..., 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.stack([edges[..., 1] / length, -edges[..., 0] / length], axis=-1)


def _extent(outline: np.ndarray, ax: np.ndarray, ay: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(P, A)`` lowest and highest projection of outlines ``(P, K, 2)`` on axes ``(ax, ay)``, corner by corner
    (elementwise minimum / maximum: numpy's reductions over an axis of 2-4 cost far more)."""
    projections = [outline[:, None, k, 0] * ax + outline[:, None, k, 1] * ay for k in range(outline.shape[1])]
    return reduce(np.minimum, projections), reduce(np.maximum, projections)


@dataclass
class Axes:
    """Outlines' separating axes ``(P, E, 2)`` and each outline's own extent on them ``(P, E)``: what the test needs
    of one side alone, so outlines met by many queries (an observation's boxes) compute it once and gather rows."""

    normals: np.ndarray
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def of(cls, outline: np.ndarray) -> "Axes":
        normals = _unit_normals(outline)
        return cls(normals, *_extent(outline, normals[..., 0], normals[..., 1]))

    def __getitem__(self, rows: np.ndarray) -> "Axes":
        return Axes(self.normals[rows], self.low[rows], self.high[rows])


def _gaps(own: Axes, other: np.ndarray) -> np.ndarray:
    """``(P, E)``: how far apart the projections of an outline (``own``, its axes) and ``other`` ``(P, K, 2)`` are on
    each of its axes (negative: overlap depth)."""
    low, high = _extent(other, own.normals[..., 0], own.normals[..., 1])
    return np.maximum(low - own.high, own.low - high)


def convex_intersects(
    first: np.ndarray, second: np.ndarray, exact: Callable[[np.ndarray], np.ndarray], second_axes: Axes | None = None
) -> np.ndarray:
    """``(P,)``: outline ``first[p]`` (``(P, K1, 2)``, convex, in ring order) shares a point with ``second[p]``.
    ``exact(indices)`` answers the undecided pairs (``shapely.intersects`` of the same outlines). ``second_axes``:
    ``Axes.of(second)`` where the caller holds it (the same numbers, gathered instead of recomputed)."""
    if len(first) == 0:
        return np.zeros(0, bool)
    second_axes = Axes.of(second) if second_axes is None else second_axes
    gaps = [*_gaps(Axes.of(first), second).T, *_gaps(second_axes, first).T]
    # the widest gap axis by axis, elementwise (numpy's any / all over an axis of 3-4 cost far more): fmax skips a
    # NaN gap (some other axis may still separate), maximum keeps it (a NaN axis proves no overlap)
    separated = reduce(np.fmax, gaps) > MARGIN
    overlapping = reduce(np.maximum, gaps) < -MARGIN
    result = overlapping & ~separated
    undecided = np.flatnonzero(~separated & ~overlapping)
    if len(undecided):
        result[undecided] = exact(undecided)
    return result
