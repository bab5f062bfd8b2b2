"""PDM-Closed's graph searches on hand-built graphs: the roadblock BFS against a literal queue-based BFS, the lane
Dijkstra, discrete baselines."""

from collections import deque

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lead_s2r.scoring.pdm.route import LaneGraph, bfs_roadblocks, dijkstra_lanes, discrete_path


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
