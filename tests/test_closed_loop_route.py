"""Run-time navigation: GNSS with a non-zero geo reference, compass, position filter, LEAD's target points."""

import math

import numpy as np
import pytest
from closed_loop_scene import world_to_gnss

from lead_s2r.closed_loop.route import (
    GeoReference,
    PositionFilter,
    TargetPoints,
    compass_to_yaw,
    estimate_geo_reference,
    gnss_to_world,
)


def test_gnss_round_trip_with_a_non_zero_reference():
    reference = GeoReference(49.0, 8.0)  # a Town13-like reference, far from (0, 0)
    world = np.array([[0.0, 0.0], [1523.7, -2210.4], [-4800.0, 3900.5], [12.5, 7.25]])
    gnss = world_to_gnss(world, (reference.lat, reference.lon))
    estimated = estimate_geo_reference(gnss, world)
    assert estimated.lat == pytest.approx(49.0, abs=1e-9) and estimated.lon == pytest.approx(8.0, abs=1e-9)
    assert np.abs(gnss_to_world(gnss[:, 0], gnss[:, 1], estimated) - world).max() < 1e-3
    wrong = gnss_to_world(gnss[:, 0], gnss[:, 1], GeoReference(0.0, 0.0))
    assert np.abs(wrong - world).max() > 100.0  # what a fixed (0, 0) reference would do


def test_compass_to_iso_yaw():
    assert compass_to_yaw(0.0) == pytest.approx(math.pi / 2)  # north = CARLA -y = ISO +y
    assert compass_to_yaw(math.pi / 2) == pytest.approx(0.0)  # east = CARLA +x
    assert compass_to_yaw(math.pi) == pytest.approx(-math.pi / 2)
    assert compass_to_yaw(float("nan")) == pytest.approx(math.pi / 2)


def test_position_filter_smooths_noisy_gnss():
    rng = np.random.default_rng(0)
    dt, speed = 0.05, 8.0
    truth = np.column_stack([speed * dt * np.arange(200), np.zeros(200)])
    noisy = truth + rng.normal(0, 0.5, truth.shape)
    kalman = PositionFilter(dt)
    filtered = np.array([kalman.step(np.r_[p, 0.0, speed])[:2] for p in noisy])
    raw_error = np.linalg.norm(noisy[50:] - truth[50:], axis=1).mean()
    filtered_error = np.linalg.norm(filtered[50:] - truth[50:], axis=1).mean()
    assert filtered_error < 0.5 * raw_error


# A scripted route along +x (world ISO) and the ego driving it with yaw 0. RoadOption: 1 LEFT, 4 LANEFOLLOW.
ROUTE = np.array([[0.0, 0.0], [8.0, 0.0], [14.0, 0.0], [80.0, 0.0], [90.0, 0.0]])
COMMANDS = [4, 1, 1, 4, 4]
AXLE = 1.389  # vehicle centre -> rear axle: target points move forward by this
# ego x -> (previous, current, next) x in the vehicle-centre frame, command, next command; worked by hand:
EXPECTED = [
    (0.0, (0.0, 8.0, 14.0), 4, 1),  # nothing within 5 m but P0; dense, and the 4 m planner agrees
    (3.5, (-3.5, 4.5, 10.5), 4, 1),  # 5 m pops P0 (P1 at 4.5 m), but P1-P2 are dense: the 4 m planner keeps P0
    (10.0, (4.0, 70.0, 70.0), 1, 4),  # P2 at 4 m is popped to; next P3 at 80 m > 50 m -> the current point
    (79.0, (1.0, 11.0, 11.0), 4, 4),  # two points left: current = next
    (88.0, (-8.0, 2.0, 2.0), 4, 4),  # never fewer than two
]


def test_target_points_and_commands_follow_the_hand_worked_sequence():
    navigator = TargetPoints(ROUTE, COMMANDS)
    for x, xs, command, next_command in EXPECTED:
        navigation = navigator.step(np.array([x, 0.0, 0.0]))
        want = np.column_stack([np.array(xs) + AXLE, np.zeros(3)])
        np.testing.assert_allclose(navigation.target_points, want, atol=1e-5, err_msg=f"ego at x={x}")
        assert (navigation.command, navigation.next_command) == (command, next_command), f"ego at x={x}"


def test_without_the_adaptive_and_distant_rules():
    navigator = TargetPoints(ROUTE, COMMANDS, adaptive=False, skip_distant=False)
    navigator.step(np.array([0.0, 0.0, 0.0]))
    navigation = navigator.step(np.array([3.5, 0.0, 0.0]))
    np.testing.assert_allclose(navigation.target_points[:, 0], np.array([4.5, 10.5, 76.5]) + AXLE, atol=1e-5)
    assert (navigation.command, navigation.next_command) == (1, 1)


def test_target_points_are_in_the_iso_ego_frame():
    # ego at the origin facing world ISO +y: a point 10 m along +y is ahead, one at +x is to the right (y < 0)
    navigator = TargetPoints(np.array([[0.0, 0.0], [0.0, 10.0], [10.0, 10.0]]), [4, 1, 4], adaptive=False)
    navigation = navigator.step(np.array([0.0, 0.0, math.pi / 2]))
    np.testing.assert_allclose(navigation.target_points, [[AXLE, 0], [10 + AXLE, 0], [10 + AXLE, -10]], atol=1e-5)
