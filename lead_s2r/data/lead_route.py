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


def lead_route(route: np.ndarray, count: int) -> dict[str, torch.Tensor]:
    """``count`` (x, y) route targets from the route's (K, 2) points ahead (ego at the origin): ``route`` float32
    and ``route_valid`` (all False when the route has fewer than two distinct points, or the pursuit cannot go on)."""
    route = np.asarray(route, np.float64)[:, :2]
    _, first = np.unique(route, axis=0, return_index=True)
    route = route[np.sort(first)]
    points = np.zeros((count, 2))
    if len(route) < min(2, count):  # nothing to pursue, or no line to continue on
        return _targets(points, valid=False)
    last, previous = np.zeros(2), np.zeros(2)
    for i in range(count):
        radius = FIRST_DISTANCE_M if i == 0 else SPACING_M
        if i < len(route):
            point = _towards(last, route[i], route[i] - previous, radius)
            previous = route[i]
        else:
            point = _on_line(last, route[-2], route[-1], radius)
        if point is None:
            return _targets(np.zeros((count, 2)), valid=False)
        points[i] = last = point
    if not np.isfinite(points).all():  # a route point that is not a number
        return _targets(np.zeros((count, 2)), valid=False)
    return _targets(points, valid=True)


def _towards(centre: np.ndarray, target: np.ndarray, step: np.ndarray, radius: float) -> np.ndarray | None:
    """The point ``radius`` from ``centre`` on the line through it and ``target``, on the side ``step`` points to."""
    line = target - centre
    length = float(np.hypot(*line))
    if length == 0.0:
        return None
    unit = line / length
    return centre + radius * unit if float(unit @ step) > 0 else centre - radius * unit


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
