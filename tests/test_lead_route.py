"""LEAD's route planner, shared by the 123D adapter and the closed-loop agent: the popping rule of LEAD's
``RoutePlanner.run_step`` on hand-worked routes, including the two edges where a re-reading of it once went wrong."""

import numpy as np

from lead_s2r.formats.lead_route import RoutePlanner, merge_duplicates, previous_current_next
from lead_s2r.geometry import points_to_local


def first_points(route: list[tuple[np.ndarray, int]]) -> list[list[float]]:
    return [point.tolist() for point, _ in route]


def test_pops_to_the_farthest_point_within_reach_and_keeps_two():
    points = np.array([[0.0, 0.0], [4.0, 0.0], [6.0, 0.0], [20.0, 0.0], [90.0, 0.0]])
    planner = RoutePlanner(points, [4, 1, 1, 4, 4], min_distance=5.0)
    route = planner.step(np.array([1.0, 0.0]))  # within 5 m: (4, 0) at 3 m and (6, 0) at 5 m -> pop to the latter
    assert first_points(route)[0] == [6.0, 0.0]
    targets, commands = previous_current_next(route)
    assert points_to_local(targets, np.array([1.0, 0.0, 0.0])).tolist() == [[5.0, 0.0], [19.0, 0.0], [89.0, 0.0]]
    assert commands == [1, 4, 4]  # the command is the previous point's
    assert len(planner.step(np.array([100.0, 0.0]))) == 3  # nothing within reach
    route = planner.step(np.array([19.0, 0.0]))
    assert first_points(route) == [[20.0, 0.0], [90.0, 0.0]]  # at least two stay
    targets, commands = previous_current_next(route)
    np.testing.assert_allclose(
        points_to_local(targets, np.array([19.0, 0.0, np.pi / 2])), [[0.0, -1.0], [0.0, -71.0], [0.0, -71.0]], atol=1e-9
    )
    assert commands == [4, 4, 4]


def test_the_first_point_is_never_a_candidate():
    """LEAD walks from the second point: the ego 2.5 m past the first point and 0.5 m short of the second pops the
    first, although the first lies farther away within reach."""
    planner = RoutePlanner(np.array([[0.0, 0.0], [3.0, 0.0], [10.0, 0.0], [20.0, 0.0]]), [4] * 4, min_distance=3.25)
    assert first_points(planner.step(np.array([2.5, 0.0])))[0] == [3.0, 0.0]


def test_the_look_ahead_takes_the_point_that_passes_fifty_metres():
    """The path is checked before the next segment is added: a point 60 m down the path still counts when the one
    before it lies within 50 m, and the walk stops after it."""
    points = np.array([[0.0, 0.0], [30.0, 0.0], [60.0, 0.0], [61.0, 0.0]])
    planner = RoutePlanner(points, [4] * 4, min_distance=5.0)
    assert first_points(planner.step(np.array([58.0, 0.0])))[0] == [60.0, 0.0]
    planner = RoutePlanner(np.array([[0.0, 0.0], [30.0, 0.0], [60.0, 0.0], [61.0, 0.0], [62.0, 0.0]]), [4] * 5, 5.0)
    assert first_points(planner.step(np.array([61.5, 0.0])))[0] == [60.0, 0.0]  # 61 and 62 lie past the walk's end


def test_every_consecutive_duplicate_merges_before_the_three_are_chosen():
    p, q, r = np.array([1.0, 2.0]), np.array([5.0, 2.0]), np.array([9.0, 2.0])
    assert [c for _, c in merge_duplicates([(p, 4), (p.copy(), 1), (q, 2)])] == [4, 2]
    assert len(merge_duplicates([(p, 4), (p.copy(), 1)])) == 2
    targets, commands = previous_current_next([(p, 4), (p.copy(), 1), (q, 2), (r, 3)])
    assert targets.tolist() == [p.tolist(), q.tolist(), r.tolist()] and commands == [4, 2, 3]
