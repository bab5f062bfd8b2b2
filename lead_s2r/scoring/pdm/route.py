"""PDM-Closed's route: the lane graph of ``scoring.npz``, route-roadblock correction and the Dijkstra centreline.

NAVSIM measures progress along the centreline PDM-Closed builds, and DDC's on-route lanes are the interior lanes of
the *corrected* route, so both must be rebuilt exactly as tuplan_garage's planner does (``route_utils.py``,
``bfs_roadblock.py``, ``dijkstra.py``, ``abstract_pdm_planner.py``). Behaviours reproduced on purpose:

* roadblock candidates are ROADBLOCK / ROADBLOCK_CONNECTOR polygons within 1 m of the rear axle, on-route
  candidates need a lane with heading error < pi/4 and displacement < 3 m; else the nearest of each layer;
* the roadblock BFS keeps no visited set and the parent of a node at depth d is the *last* node at depth d - 1
  that reaches it; it is computed level by level over distinct nodes, which gives the same path in linear time;
* route loops are cut at the first roadblock connector overlapping an earlier one by more than 1 m^2;
* the start lane is the on-route lane under the rear axle with the least heading error at its nearest baseline
  point, else the first on-route lane holding the ego centre, else the one nearest to the ego footprint;
* Dijkstra costs are baseline lengths, ties go to the earliest queued lane, and without a path to the 30th route
  roadblock the cheapest lane of the deepest level ends the path;
* the centreline concatenates whole baselines (shared end points included), each point's heading pointing at its
  successor and the last copying the one before.

The only data difference: ``scoring.npz`` holds the map within ``map_radius`` (100 m) of the ego, so route
roadblocks beyond it are absent (the official planner would load them to extend the centreline further ahead).
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import numpy as np
import shapely

from lead_s2r.geometry import wrap_angle
from lead_s2r.schema import MapKind
from lead_s2r.scoring.pdm.scene import ragged_polygons
from lead_s2r.scoring.pdm.vehicle import PACIFICA, VehicleParameters

#: route_utils.py constants
CANDIDATE_RADIUS = 1.0
HEADING_ERROR_THRESHOLD = np.pi / 4
DISPLACEMENT_ERROR_THRESHOLD = 3.0
SEARCH_DEPTH_BACKWARD = 15
SEARCH_DEPTH_FORWARD = 30
LOOP_AREA = 1.0
#: abstract_pdm_planner.py: Dijkstra towards the 30th route roadblock from the start lane's
CENTERLINE_SEARCH_DEPTH = 30

BLOCK_KINDS = (MapKind.ROADBLOCK, MapKind.ROADBLOCK_CONNECTOR)
LANE_KINDS = (MapKind.LANE, MapKind.LANE_CONNECTOR)


class RouteError(ValueError):
    """A scene has no route PDM-Closed can follow; the message names the sample."""


def discrete_path(points: np.ndarray) -> np.ndarray:
    """(Q, 2) polyline -> (Q, 3) x, y, heading: each point heads to its successor, the last copies the one before
    (nuPlan's ``extract_discrete_polyline``)."""
    points = np.asarray(points, np.float64)
    step = np.diff(points, axis=0)
    heading = np.arctan2(step[:, 1], step[:, 0])
    return np.column_stack([points, np.append(heading, heading[-1:])])


@dataclass
class LaneGraph:
    """The roadblock and lane graph of one scene's map context, keyed by nuPlan id (a roadblock wins a clash)."""

    block_polygon: dict[int, shapely.Polygon]  # roadblocks and roadblock connectors
    block_is_connector: dict[int, bool]
    block_out: dict[int, list[int]]
    block_in: dict[int, list[int]]
    block_lanes: dict[int, list[int]]  # interior lanes / lane connectors, in map order
    blocks_by_kind: dict[int, list[int]]  # MapKind -> block ids in map order
    lane_polygon: dict[int, shapely.Polygon]
    lane_block: dict[int, int]
    lane_out: dict[int, list[int]]
    lane_path: dict[int, np.ndarray]  # (Q, 3) discrete baseline
    lane_length: dict[int, float]
    lane_speed_limit: dict[int, float]  # NaN where the map has none

    @classmethod
    def from_scoring(cls, scoring: dict[str, Any]) -> "LaneGraph":
        """Build from the arrays of a sample's ``scoring`` field (layout: docs/datasets/navsim.md)."""
        polygons = ragged_polygons(scoring["polygon_xy"], scoring["polygon_offsets"])
        ids = np.asarray(scoring["polygon_id"], np.int64).tolist()
        kinds = np.asarray(scoring["polygon_kind"]).astype(int).tolist()
        parents = np.asarray(scoring["polygon_parent"], np.int64).tolist()
        limits = np.asarray(scoring["polygon_speed_limit"], np.float64).tolist()
        graph = cls({}, {}, {}, {}, {}, {int(k): [] for k in BLOCK_KINDS}, {}, {}, {}, {}, {}, {})
        for polygon, fid, kind, parent, limit in zip(polygons, ids, kinds, parents, limits, strict=True):
            if kind in BLOCK_KINDS and not (fid in graph.block_polygon and kind == MapKind.ROADBLOCK_CONNECTOR):
                graph.block_polygon[fid] = polygon
                graph.block_is_connector[fid] = kind == MapKind.ROADBLOCK_CONNECTOR
                graph.blocks_by_kind[kind].append(fid)
                graph.block_out.setdefault(fid, [])
                graph.block_in.setdefault(fid, [])
            elif kind in LANE_KINDS:
                graph.lane_polygon[fid] = polygon
                graph.lane_block[fid] = parent
                graph.lane_speed_limit[fid] = limit
                graph.lane_out.setdefault(fid, [])
        for fid, parent in graph.lane_block.items():
            graph.block_lanes.setdefault(parent, []).append(fid)
        for connector, source, target in np.asarray(scoring["roadblock_connector_edges"], np.int64).reshape(-1, 3):
            graph.block_out.setdefault(int(source), []).append(int(connector))
            graph.block_in.setdefault(int(connector), []).append(int(source))
            graph.block_out.setdefault(int(connector), []).append(int(target))
            graph.block_in.setdefault(int(target), []).append(int(connector))
        for connector, exit_lane, entry_lane in np.asarray(scoring["lane_connector_edges"], np.int64).reshape(-1, 3):
            graph.lane_out.setdefault(int(exit_lane), []).append(int(connector))
            graph.lane_out.setdefault(int(connector), []).append(int(entry_lane))
        offsets = np.asarray(scoring["centerline_offsets"], np.int64)
        xy = np.asarray(scoring["centerline_xy"], np.float64)
        for fid, (start, end) in zip(np.asarray(scoring["centerline_id"]).tolist(), pairwise(offsets), strict=True):
            if end - start >= 2:
                graph.lane_path[fid] = discrete_path(xy[start:end])
                graph.lane_length[fid] = float(np.linalg.norm(np.diff(xy[start:end], axis=0), axis=1).sum())
        return graph

    def outgoing(self, block: int) -> list[int]:
        return self.block_out.get(block, [])

    def incoming(self, block: int) -> list[int]:
        return self.block_in.get(block, [])


def bfs_roadblocks(
    start: int, neighbours: Callable[[int], Sequence[int]], targets: Sequence[int], max_depth: int
) -> list[int] | None:
    """tuplan_garage's ``BreadthFirstSearchRoadBlock``: the path from ``start`` to the first target reached, in
    search order (start first), or None. Per level, the first occurrence of a node decides which target is found
    first and the last occurrence which parent a node of the next level keeps."""
    wanted = set(targets)
    first, last = [start], [start]  # the level's distinct nodes by first / by last occurrence
    parents: list[dict[int, int]] = [{}]
    for depth in range(1, max_depth + 1):
        found = next((node for node in first if node in wanted), None)
        if found is not None:
            path = [found]
            for level in range(depth - 1, 0, -1):
                path.append(parents[level][path[-1]])
            return path[::-1]
        next_first: dict[int, None] = {}
        for node in first:
            for successor in neighbours(node):
                next_first.setdefault(successor)
        next_last: dict[int, None] = {}
        parent: dict[int, int] = {}
        for node in last:
            for successor in neighbours(node):
                next_last.pop(successor, None)
                next_last[successor] = None
                parent[successor] = node
        if not next_first:
            return None
        first, last = list(next_first), list(next_last)
        parents.append(parent)
    return None


def _nearest_point_errors(path: np.ndarray, pose: np.ndarray) -> tuple[float, float]:
    """(|heading error|, displacement) of ``pose`` to the nearest point of a discrete path."""
    distance = np.linalg.norm(path[:, :2] - pose[:2], axis=1)
    nearest = int(np.argmin(distance))
    return float(abs(wrap_angle(path[nearest, 2] - pose[2]))), float(distance[nearest])


def roadblock_candidates(graph: LaneGraph, route: Sequence[int], pose: np.ndarray) -> tuple[int, list[int]]:
    """``get_current_roadblock_candidates``: the roadblock the ego is most likely on and the other candidates."""
    point = shapely.Point(pose[:2])
    candidates = [
        fid
        for kind in BLOCK_KINDS
        for fid in graph.blocks_by_kind[kind]
        if shapely.dwithin(graph.block_polygon[fid], point, CANDIDATE_RADIUS)
    ]
    if not candidates:
        for kind in BLOCK_KINDS:
            blocks = graph.blocks_by_kind[kind]
            if blocks:
                distance = [shapely.distance(graph.block_polygon[fid], point) for fid in blocks]
                candidates.append(blocks[int(np.argmin(distance))])
    if not candidates:
        raise RouteError("no roadblock in the map context")
    on_route, on_route_error, off_route, off_route_error, block_errors = [], [], [], [], []
    route_set = set(route)
    for fid in candidates:
        best_displacement = np.inf
        for lane in graph.block_lanes.get(fid, []):
            if lane not in graph.lane_path:
                continue
            heading_error, displacement = _nearest_point_errors(graph.lane_path[lane], pose)
            best_displacement = min(best_displacement, displacement)
            if heading_error < HEADING_ERROR_THRESHOLD and displacement < DISPLACEMENT_ERROR_THRESHOLD:
                (on_route if fid in route_set else off_route).append(fid)
                (on_route_error if fid in route_set else off_route_error).append(displacement)
        block_errors.append(best_displacement)
    if on_route:
        return on_route[int(np.argmin(on_route_error))], on_route
    if off_route:
        return off_route[int(np.argmin(off_route_error))], off_route
    return candidates[int(np.argmin(block_errors))], candidates


def correct_route(graph: LaneGraph, route_ids: Sequence[int], pose: np.ndarray) -> list[int]:
    """``route_roadblock_correction``: prepend the way from an off-route start, fill gaps, cut loops. Route ids
    absent from the map context are dropped first (as ``_load_route_dicts`` keeps only blocks the map returns)."""
    route = [fid for fid in dict.fromkeys(int(r) for r in route_ids) if fid in graph.block_polygon]
    if not route:
        return route
    start, candidates = roadblock_candidates(graph, route, pose)
    if start not in route:
        backward = bfs_roadblocks(route[0], graph.incoming, candidates, SEARCH_DEPTH_BACKWARD)
        if backward is not None:
            route = backward[::-1][:-1] + route  # the search ran from route[0] back to a candidate
        else:
            forward = bfs_roadblocks(start, graph.outgoing, route[:3], SEARCH_DEPTH_FORWARD)
            if forward is not None:
                route = forward + route[route.index(forward[-1]) + 1 :]
    route = _fill_gaps(graph, route)
    return _cut_loops(graph, route)


def _fill_gaps(graph: LaneGraph, route: list[int]) -> list[int]:
    """Insert the roadblocks between consecutive route blocks that are not linked (path of >= 3 blocks)."""
    filled = list(route[:1])
    for current, following in pairwise(route):
        if current not in graph.block_in.get(following, []):
            path = bfs_roadblocks(current, graph.outgoing, [following], SEARCH_DEPTH_FORWARD)
            if path is not None and len(path) >= 3:
                filled.extend(path[1:-1])
        filled.append(following)
    return filled


def _cut_loops(graph: LaneGraph, route: list[int]) -> list[int]:
    """``remove_route_loops``: end the route before a roadblock connector overlapping an earlier connector."""
    seen: list[shapely.Polygon] = []
    for index, fid in enumerate(route):
        if not graph.block_is_connector[fid]:
            continue
        polygon = graph.block_polygon[fid]
        if seen and any(shapely.area(shapely.intersection(other, polygon)) > LOOP_AREA for other in seen):
            return route[:index]
        seen.append(polygon)
    return route


def route_lanes(graph: LaneGraph, route: Sequence[int]) -> list[int]:
    """Interior lanes of the route blocks, in route order (``_load_route_dicts``)."""
    return list(dict.fromkeys(lane for fid in route for lane in graph.block_lanes.get(fid, [])))


def starting_lane(
    graph: LaneGraph, lanes: Sequence[int], pose: np.ndarray, vehicle: VehicleParameters = PACIFICA
) -> int:
    """``_get_starting_lane`` for a rear-axle ``pose``: see the module docstring."""
    point = shapely.Point(pose[:2])
    under, errors = [], []
    for lane in lanes:
        if lane in graph.lane_path and shapely.intersects(graph.lane_polygon[lane], point):
            under.append(lane)
            errors.append(_nearest_point_errors(graph.lane_path[lane], pose)[0])
    if under:
        return under[int(np.argmin(errors))]
    heading = np.array([np.cos(pose[2]), np.sin(pose[2])])
    centre = shapely.Point(pose[:2] + vehicle.rear_axle_to_center * heading)
    footprint = ego_footprint(pose, vehicle)
    best, best_distance = None, np.inf
    for lane in lanes:
        polygon = graph.lane_polygon[lane]
        if shapely.contains(polygon, centre):
            return lane
        distance = shapely.distance(polygon, footprint)
        if distance < best_distance:
            best, best_distance = lane, distance
    if best is None:
        raise RouteError("the route has no lane in the map context")
    return best


def pose_boxes(poses: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Shapely boxes ``(N,)`` of poses ``(N, 3)`` with ``corners (4, 2)`` (or ``(N, 4, 2)``) in each pose's frame."""
    cos, sin = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = poses[:, None, 0] + cos * corners[..., 0] - sin * corners[..., 1]
    y = poses[:, None, 1] + sin * corners[..., 0] + cos * corners[..., 1]
    return shapely.polygons(np.stack([x, y], axis=-1))


def ego_footprints(poses: np.ndarray, vehicle: VehicleParameters = PACIFICA) -> np.ndarray:
    """The ego boxes (N,) of rear-axle poses (N, 3)."""
    front, rear, half_width = vehicle.front_length, -vehicle.rear_length, vehicle.width / 2
    corners = np.array([[front, half_width], [rear, half_width], [rear, -half_width], [front, -half_width]])
    return pose_boxes(np.asarray(poses, np.float64).reshape(-1, 3), corners)


def ego_footprint(pose: np.ndarray, vehicle: VehicleParameters = PACIFICA) -> shapely.Polygon:
    """The ego box of one rear-axle pose."""
    return ego_footprints(pose, vehicle)[0]


def dijkstra_lanes(graph: LaneGraph, start: int, candidates: Sequence[int], target_block: int) -> list[int]:
    """tuplan_garage's lane ``Dijkstra`` from ``start`` to any lane of ``target_block`` over ``candidates``."""
    allowed = set(candidates)
    queue, dist, depth = [start], [1.0], [1]
    parent: dict[int, int | None] = {start: None}
    expanded: dict[int, tuple[float, int]] = {}  # lane -> (distance, depth), in the order of expansion
    end = None
    while queue:
        index = min(range(len(dist)), key=lambda i: (dist[i], i))
        lane, lane_dist, lane_depth = queue.pop(index), dist.pop(index), depth.pop(index)
        if graph.lane_block.get(lane) == target_block:
            end = lane
            break
        expanded[lane] = (lane_dist, lane_depth)
        for successor in graph.lane_out.get(lane, []):
            if successor not in allowed:
                continue
            alternative = lane_dist + graph.lane_length.get(successor, 0.0)
            if successor not in expanded and successor not in queue:
                parent[successor] = lane
                queue.append(successor)
                dist.append(alternative)
                depth.append(lane_depth + 1)
            elif successor in queue:
                position = queue.index(successor)
                if alternative < dist[position]:
                    parent[successor] = lane
                    dist[position] = alternative
                    depth[position] = lane_depth + 1
    if end is None:
        deepest = max(level for _, level in expanded.values())
        end = min((cost, i, lane) for i, (lane, (cost, level)) in enumerate(expanded.items()) if level == deepest)[2]
    path = [end]
    while parent[path[-1]] is not None:
        path.append(parent[path[-1]])
    return path[::-1]


@dataclass
class Route:
    """PDM-Closed's route as a scene takes it: the corrected roadblocks' lanes, the centreline from the start lane."""

    lane_ids: list[int]
    centerline: np.ndarray  # (L, 3)
    speed_limit: float  # of the start lane; NaN where the map has none


def plan_route(graph: LaneGraph, route_ids: Sequence[int]) -> Route:
    """Route correction, start lane and Dijkstra centreline for the ego at the origin of its frame (rear axle)."""
    pose = np.zeros(3)
    roadblocks = correct_route(graph, route_ids, pose)
    lanes = route_lanes(graph, roadblocks)
    if not lanes:
        raise RouteError("no lane of the route's roadblocks lies in the map context")
    start = starting_lane(graph, lanes, pose)
    block = graph.lane_block[start]
    first = roadblocks.index(block) if block in roadblocks else 0
    window = roadblocks[first : first + CENTERLINE_SEARCH_DEPTH]
    plan = dijkstra_lanes(graph, start, lanes, window[-1])
    paths = [graph.lane_path[lane] for lane in plan if lane in graph.lane_path]
    if not paths:
        raise RouteError("the route's lanes have no baseline path in the map context")
    return Route(lanes, np.concatenate(paths), graph.lane_speed_limit[start])
