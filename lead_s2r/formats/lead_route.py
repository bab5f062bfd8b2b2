"""LEAD's route planner (``lead/common/route_planner.py``): which points of the sparse plan are the previous, current
and next target points. Shared by the 123D adapter, which labels recorded frames with them, and the closed-loop
agent, which feeds them live, for the reason :mod:`lead_s2r.formats.carla_rig` is shared: a popping rule that
differed between the two would show the model target points at run time unlike those it was trained on.
"""

import math
from collections import deque

import numpy as np

#: The planner only looks this far (path length) down the route when popping (LEAD's ``max_distance``).
MAX_LOOK_DISTANCE = 50.0


class RoutePlanner:
    """LEAD's ``RoutePlanner.run_step``: walk the plan from its second point while the path walked so far is at most
    ``MAX_LOOK_DISTANCE``; pop every point before the farthest one lying within ``min_distance`` of the ego; at least
    2 points always stay."""

    def __init__(self, points: np.ndarray, commands: list[int], min_distance: float) -> None:
        if len(points) != len(commands) or not len(points):
            raise ValueError(f"a route needs one command per point and at least one point; got {len(points)} points"
                             f" and {len(commands)} commands")  # fmt: skip
        self.route = deque(zip(np.asarray(points, np.float64)[:, :2], map(int, commands), strict=True))
        self.min_distance = min_distance

    def step(self, position: np.ndarray) -> list[tuple[np.ndarray, int]]:
        """The remaining route, (point, RoadOption) pairs, after popping for the ego at ``position`` (x, y)."""
        if len(self.route) > 2:
            pop, farthest, path = 0, -math.inf, 0.0
            for i in range(1, len(self.route)):
                if path > MAX_LOOK_DISTANCE:
                    break
                path += float(np.linalg.norm(self.route[i][0] - self.route[i - 1][0]))
                distance = float(np.linalg.norm(self.route[i][0] - position[:2]))
                if farthest < distance <= self.min_distance:
                    pop, farthest = i, distance
            for _ in range(pop):
                if len(self.route) > 2:
                    self.route.popleft()
        return list(self.route)


def merge_duplicates(route: list[tuple[np.ndarray, int]]) -> list[tuple[np.ndarray, int]]:
    """Drop a point equal (``np.allclose``) to the one before it, unless only 2 remain."""
    if len(route) <= 2:
        return route
    merged = [route[0]]
    for point, command in route[1:]:
        if not np.allclose(point, merged[-1][0]):
            merged.append((point, command))
    return merged


def previous_current_next(route: list[tuple[np.ndarray, int]]) -> tuple[np.ndarray, list[int]]:
    """The previous, current and next target points (3, 2) of a stepped route, duplicates merged, and their
    RoadOptions; with 2 points left the current one is also the next."""
    route = merge_duplicates(route)
    chosen = route[:3] if len(route) > 2 else [route[0], route[-1], route[-1]]
    return np.array([point for point, _ in chosen]), [command for _, command in chosen]
