"""Do two convex outlines share a point (GEOS ``intersects``)? The separating-axis test in numpy for the many pairs NC
and TTC check (ego box against agent box, ego front edge against agent box), GEOS for the few that floats cannot decide.

Two convex outlines are disjoint exactly when the projections on one of their edge normals leave a gap (a box has two
edge directions, a segment one). Computed in floats, a projection is off by far less than :data:`MARGIN`, so a gap wider
than it on some axis means disjoint and an overlap deeper than it on every axis means intersecting, whatever the
rounding; a pair within the margin (touching, or degenerate with a zero-length edge) goes to ``shapely.intersects`` on
the same corners, which is what NAVSIM's STRtree query decides. The answer is GEOS's for every pair, and a pair's answer
does not depend on the pairs beside it.
"""

from collections.abc import Callable
from dataclasses import dataclass
from functools import reduce

import numpy as np

#: [m] along a unit axis: separations or overlaps within this are left to GEOS (float error is ~1e-13 m at 1 km)
MARGIN = 1e-7


def _corners(outline: np.ndarray) -> np.ndarray:
    """``(K, 2, P)``: outlines ``(P, K, 2)`` corner by corner and coordinate by coordinate, each a contiguous ``(P,)``
    row, so every step below is one pass over the pairs (numpy's loops over an axis of 2-4 cost far more)."""
    return np.ascontiguousarray(np.moveaxis(outline, 0, -1))


def _unit_normals(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(E, P)`` x and y of the unit normals of the edges of outlines ``(K, 2, P)`` that can separate: a box's
    first two edges (its other two are parallel to them, to rounding far below :data:`MARGIN`), a segment's (K = 2)
    one edge."""
    edges = corners[1:3] - corners[:2] if len(corners) > 2 else corners[1:] - corners[:1]  # (E, 2, P)
    length = np.hypot(edges[:, 0], edges[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        return edges[:, 1] / length, -edges[:, 0] / length


def _extent(corners: np.ndarray, nx: np.ndarray, ny: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(E, P)`` lowest and highest projection of outlines ``(K, 2, P)`` on axes ``(nx, ny)``, corner by corner."""
    projections = [x * nx + y * ny for x, y in corners]
    return reduce(np.minimum, projections), reduce(np.maximum, projections)


@dataclass
class Axes:
    """Outlines' separating axes ``(E, P)`` (x and y of the unit normals) and each outline's own extent on them:
    what the test needs of one side alone, so outlines met by many queries (an observation's boxes) compute it once
    and gather columns."""

    nx: np.ndarray
    ny: np.ndarray
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def of(cls, outline: np.ndarray) -> "Axes":
        """The axes of outlines ``(P, K, 2)``."""
        return cls._of(_corners(outline))

    @classmethod
    def _of(cls, corners: np.ndarray) -> "Axes":
        nx, ny = _unit_normals(corners)
        return cls(nx, ny, *_extent(corners, nx, ny))

    def __getitem__(self, rows: np.ndarray) -> "Axes":
        # np.take: the same columns, far faster than fancy indexing after a slice
        return Axes(*(np.take(part, rows, axis=1) for part in (self.nx, self.ny, self.low, self.high)))


def _gaps(own: Axes, other: np.ndarray) -> np.ndarray:
    """``(E, P)``: how far apart the projections of an outline (``own``, its axes) and ``other`` ``(K, 2, P)`` are
    on each of its axes (negative: overlap depth)."""
    low, high = _extent(other, own.nx, own.ny)
    return np.maximum(low - own.high, own.low - high)


def convex_intersects(
    first: np.ndarray, second: np.ndarray, exact: Callable[[np.ndarray], np.ndarray], second_axes: Axes | None = None
) -> np.ndarray:
    """``(P,)``: outline ``first[p]`` (``(P, K1, 2)``, convex, in ring order) shares a point with ``second[p]``.
    ``exact(indices)`` answers the undecided pairs (``shapely.intersects`` of the same outlines). ``second_axes``:
    ``Axes.of(second)`` where the caller holds it (the same numbers, gathered instead of recomputed)."""
    if len(first) == 0:
        return np.zeros(0, bool)
    first, second = _corners(first), _corners(second)
    second_axes = Axes._of(second) if second_axes is None else second_axes
    gaps = [*_gaps(Axes._of(first), second), *_gaps(second_axes, first)]
    # the widest gap axis by axis, elementwise (numpy's any / all over an axis of 3-4 cost far more): fmax skips a
    # NaN gap (some other axis may still separate), maximum keeps it (a NaN axis proves no overlap)
    separated = reduce(np.fmax, gaps) > MARGIN
    overlapping = reduce(np.maximum, gaps) < -MARGIN
    result = overlapping & ~separated
    undecided = np.flatnonzero(~separated & ~overlapping)
    if len(undecided):
        result[undecided] = exact(undecided)
    return result
