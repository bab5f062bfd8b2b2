"""The route target LEAD's planner learns: ``smooth_path`` of LEAD's CARLA loader (``carla_dataset_utils.py``,
LEAD commit 4489176), written from its definition.

LEAD does not resample the route by arc length. It pursues it: the first point is 2.5 m from the ego (a circle
around the origin) on the line towards the route's first point, and each next point 1 m from the last one on the
line from it towards the next route point, whichever of the line's two crossings with the circle lies further along
the route's own step there. Past the route's end it continues on the line through the last two route points.
Duplicate route points are dropped first (the first of equal rows is kept, in order). On a curve the points cut
slightly inside the arc: on LEAD's generated left turn they sit up to 1 mm from the arc-length resampling.
"""

import numpy as np
import torch

#: LEAD's ``target_first_distance`` and the spacing after it, metres.
FIRST_DISTANCE_M, SPACING_M = 2.5, 1.0

Vector = tuple[float, float]


def lead_route(route: np.ndarray, count: int) -> dict[str, torch.Tensor]:
    """``count`` (x, y) route targets from the route's (K, 2) points ahead (ego at the origin): ``route`` float32
    and ``route_valid`` (all False when the route has fewer than two distinct points, or the pursuit cannot go on).

    The pursuit runs on Python floats (numpy's per-call cost on 2-vectors was most of its time) with the operations
    numpy did: IEEE subtraction, division and products, numpy's ``hypot``, and the side of each crossing from the
    dot product's sign, taken from numpy's own dot where two roundings could disagree on it."""
    route = _distinct_rows(np.asarray(route, np.float64)[:, :2])
    if len(route) < min(2, count):  # nothing to pursue, or no line to continue on
        return _targets(np.zeros((count, 2)), valid=False)
    rows = route[:count].tolist()
    points: list[Vector] = []
    last = previous = (0.0, 0.0)
    for i in range(count):
        radius = FIRST_DISTANCE_M if i == 0 else SPACING_M
        if i < len(rows):
            target = rows[i]
            point = _towards(last, target, (target[0] - previous[0], target[1] - previous[1]), radius)
            previous = target
        else:
            on_line = _on_line(np.array(last), route[-2], route[-1], radius)
            point = None if on_line is None else tuple(on_line.tolist())
        if point is None:
            return _targets(np.zeros((count, 2)), valid=False)
        points.append(last := point)
    targets = np.array(points, np.float64).reshape(count, 2)
    if not np.isfinite(targets).all():  # a route point that is not a number
        return _targets(np.zeros((count, 2)), valid=False)
    return _targets(targets, valid=True)


def _distinct_rows(route: np.ndarray) -> np.ndarray:
    """``route`` without repeated rows, the first of equal rows kept, in order, as ``np.unique(axis=0)`` found them
    (rows equal as floats: -0.0 equals 0.0). A NaN never equals itself here, which ``np.unique`` may not hold, but
    that changes no target: every row before the first row with a NaN is the same either way, and if the pursuit
    reaches that row the targets are invalid."""
    distinct = dict.fromkeys(map(tuple, route.tolist()))  # a key keeps its first row
    return route if len(distinct) == len(route) else np.array(list(distinct), np.float64).reshape(-1, 2)


def _towards(centre: Vector, target: Vector, step: Vector, radius: float) -> Vector | None:
    """The point ``radius`` from ``centre`` on the line through it and ``target``, on the side ``step`` points to."""
    line_x, line_y = target[0] - centre[0], target[1] - centre[1]
    length = float(np.hypot(line_x, line_y))
    if length == 0.0:
        return None
    unit_x, unit_y = line_x / length, line_y / length
    along = _dot_sign(unit_x, unit_y, step[0], step[1])
    if along > 0:
        return centre[0] + radius * unit_x, centre[1] + radius * unit_y
    return centre[0] - radius * unit_x, centre[1] - radius * unit_y


def _dot_sign(ax: float, ay: float, bx: float, by: float) -> float:
    """``a @ b`` as numpy computes it for 2-vectors, up to its last bit: only its sign is used. The plain sum of
    the rounded products can differ from numpy's (BLAS may fuse a multiply-add) in the last bits only, so where
    it is not clear of zero by far more than that, numpy's dot decides."""
    x, y = ax * bx, ay * by
    dot = x + y
    if abs(dot) > 1e-12 * (abs(x) + abs(y)) + 1e-300:  # the floor: products rounded as subnormals
        return dot
    return float(np.array([ax, ay]) @ np.array([bx, by]))


def _on_line(centre: np.ndarray, start: np.ndarray, end: np.ndarray, radius: float) -> np.ndarray | None:
    """The crossing of the circle (``centre``, ``radius``) with the line ``start`` -> ``end`` furthest along it."""
    direction = end - start
    offset = start - centre
    a, b, c = float(direction @ direction), 2 * float(direction @ offset), float(offset @ offset) - radius**2
    discriminant = b * b - 4 * a * c
    if a == 0.0 or discriminant < 0:
        return None
    return start + (-b + np.sqrt(discriminant)) / (2 * a) * direction


def _targets(points: np.ndarray, valid: bool) -> dict[str, torch.Tensor]:
    return {
        "route": torch.from_numpy(points.astype(np.float32)),
        "route_valid": torch.full((len(points),), valid, dtype=torch.bool),
    }
