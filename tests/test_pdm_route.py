"""PDM-Closed's graph searches on hand-built graphs: the roadblock BFS against a literal queue-based BFS, the lane
Dijkstra, discrete baselines."""

from collections import deque

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lead_s2r.schema import MapKind
from lead_s2r.scoring.pdm.route import LaneGraph, bfs_roadblocks, correct_route, dijkstra_lanes, discrete_path


def queue_bfs(start: int, graph: dict[int, list[int]], targets: list[int], max_depth: int) -> list[int] | None:
    """tuplan_garage's BreadthFirstSearchRoadBlock as written: a queue with level markers, no visited set, and
    the parent of (node, depth) overwritten by every later expansion."""
    queue: deque = deque([start, None])
    parent: dict[tuple[int, int], int | None] = {(start, 1): None}
    depth = 1
    while queue:
        node = queue.popleft()
        if depth > max_depth:
            break
        if node is None:
            depth += 1
            queue.append(None)
            if queue[0] is None:
                break
            continue
        if node in targets:
            path, level = [node], depth
            while parent[(path[-1], level)] is not None:
                path.append(parent[(path[-1], level)])
                level -= 1
            return path[::-1]
        for successor in graph.get(node, []):
            queue.append(successor)
            parent[(successor, depth + 1)] = node
    return None


def test_bfs_keeps_the_last_parent_and_finds_the_first_target() -> None:
    graph = {1: [2, 3], 2: [4], 3: [4], 4: [5]}
    assert bfs_roadblocks(1, lambda n: graph.get(n, []), [5], 10) == [1, 3, 4, 5]
    assert bfs_roadblocks(1, lambda n: graph.get(n, []), [3, 2], 10) == [1, 2]
    assert bfs_roadblocks(1, lambda n: graph.get(n, []), [5], 3) is None  # 5 lies at depth 4
    assert bfs_roadblocks(1, lambda n: graph.get(n, []), [1], 1) == [1]


@settings(max_examples=200, deadline=None)
@given(
    edges=st.lists(st.tuples(st.integers(0, 6), st.integers(0, 6)), max_size=16),
    target=st.integers(0, 6),
    depth=st.integers(1, 7),
)
def test_bfs_matches_the_queue_algorithm(edges: list[tuple[int, int]], target: int, depth: int) -> None:
    graph: dict[int, list[int]] = {}
    for source, successor in edges:
        graph.setdefault(source, []).append(successor)
    assert bfs_roadblocks(0, lambda n: graph.get(n, []), [target], depth) == queue_bfs(0, graph, [target], depth)


def lane_graph(out: dict[int, list[int]], length: dict[int, float], block: dict[int, int]) -> LaneGraph:
    return LaneGraph({}, {}, {}, {}, {}, {}, {}, block, out, {}, length, {})


def test_dijkstra_takes_the_cheaper_branch_and_relaxes_parents() -> None:
    graph = lane_graph({1: [2, 3], 2: [4], 3: [4]}, {1: 1.0, 2: 10.0, 3: 5.0, 4: 1.0}, {1: 10, 2: 20, 3: 20, 4: 40})
    assert dijkstra_lanes(graph, 1, [1, 2, 3, 4], 40) == [1, 3, 4]
    assert dijkstra_lanes(graph, 1, [1, 2, 4], 40) == [1, 2, 4]  # lane 3 is off-route
    assert dijkstra_lanes(graph, 1, [1, 2, 3, 4], 10) == [1]  # the start lane is in the target block


def test_dijkstra_without_a_path_ends_at_the_cheapest_deepest_lane() -> None:
    graph = lane_graph({1: [2, 3], 2: [4], 3: [5]}, {2: 10.0, 3: 5.0, 4: 3.0, 5: 9.0}, {1: 1, 2: 2, 3: 2, 4: 4, 5: 5})
    # depth 3 holds lane 4 (cost 1 + 10 + 3 = 14) and lane 5 (1 + 5 + 9 = 15)
    assert dijkstra_lanes(graph, 1, [1, 2, 3, 4, 5], 99) == [1, 2, 4]


def test_discrete_path_heads_to_the_next_point_and_repeats_the_last() -> None:
    path = discrete_path(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]))
    np.testing.assert_allclose(path[:, 2], [0.0, np.pi / 2, np.pi / 2])


def scoring_of(polygons: list[tuple[int, int, int, tuple[float, float, float, float]]], **arrays: list) -> dict:
    """A ``scoring.npz`` dict of axis-aligned boxes (id, MapKind, parent, (x0, y0, x1, y1)); lanes get a centreline
    along x through their box's middle."""
    rings = [[(x0, y0), (x1, y0), (x1, y1), (x0, y1)] for *_, (x0, y0, x1, y1) in polygons]
    lanes = [(fid, box) for fid, kind, _, box in polygons if kind in (MapKind.LANE, MapKind.LANE_CONNECTOR)]
    lines = [[(x0, (y0 + y1) / 2), (x1, (y0 + y1) / 2)] for _, (x0, y0, x1, y1) in lanes]
    return {
        "polygon_xy": np.array([point for ring in rings for point in ring], np.float64),
        "polygon_offsets": np.arange(len(rings) + 1) * 4,
        "polygon_id": np.array([p[0] for p in polygons]),
        "polygon_kind": np.array([p[1] for p in polygons]),
        "polygon_parent": np.array([p[2] for p in polygons]),
        "polygon_speed_limit": np.full(len(polygons), 10.0),
        "centerline_xy": np.array([point for line in lines for point in line], np.float64).reshape(-1, 2),
        "centerline_offsets": np.arange(len(lines) + 1) * 2,
        "centerline_id": np.array([fid for fid, _ in lanes]),
        "lane_connector_edges": np.array(arrays.get("lane_edges", []), np.int64).reshape(-1, 3),
        "roadblock_connector_edges": np.array(arrays.get("block_edges", []), np.int64).reshape(-1, 3),
    }


def corridor_map() -> LaneGraph:
    """Blocks along x: X (-10..10, the ego's), then connector 5 to C (20..40) and on to D; B (-40..-20) leads to
    connector 6, which overlaps connector 5, into D. Each block has one lane (id + 100)."""
    road, connector, lane = MapKind.ROADBLOCK, MapKind.ROADBLOCK_CONNECTOR, MapKind.LANE
    blocks = [(1, road, (-10, -2, 10, 2)), (3, road, (20, -2, 40, 2)), (4, road, (50, -2, 70, 2)),
              (2, road, (-40, -2, -20, 2)), (5, connector, (10, -2, 20, 2)), (6, connector, (12, -2, 22, 2)),
              (7, connector, (40, -2, 50, 2))]  # fmt: skip
    polygons = [(fid, kind, -1, box) for fid, kind, box in blocks]
    polygons += [(fid + 100, lane, fid, box) for fid, kind, box in blocks if kind == road]
    return LaneGraph.from_scoring(scoring_of(polygons, block_edges=[[5, 1, 3], [6, 2, 4], [7, 3, 4]]))


def test_off_route_start_falls_back_to_the_forward_search() -> None:
    # the route starts at 2, which the ego's block 1 cannot reach; 1 -> 5 -> 3 reaches the route's second block
    assert correct_route(corridor_map(), [2, 3, 7, 4], np.zeros(3)) == [1, 5, 3, 7, 4]
    # off route behind a reachable start: the backward search prepends the way
    assert correct_route(corridor_map(), [3, 7, 4], np.zeros(3)) == [1, 5, 3, 7, 4]


def test_route_is_cut_before_a_connector_overlapping_an_earlier_one() -> None:
    assert correct_route(corridor_map(), [1, 5, 3, 7, 4, 6], np.zeros(3)) == [1, 5, 3, 7, 4]
