"""Closed-loop controllers on hand-worked numbers and on a kinematic bicycle following a predicted route."""

import math

import numpy as np
import pytest

from lead_s2r.closed_loop.controllers import (
    Control,
    Creeper,
    LateralPID,
    PIDController,
    StopSignSlowdown,
    WaypointController,
    decode_target_speed,
    gate,
    lookahead_index,
    throttle_brake,
)
from lead_s2r.geometry import points_to_local

WHEEL_BASE = 2.85
#: Assumed front-wheel angle at full steer of CARLA's Lincoln MKZ (the test's actuator model, not LEAD's).
MAX_WHEEL_ANGLE = math.radians(70.0)
DT = 0.05


def circle_route(pose: np.ndarray, radius: float) -> np.ndarray:
    """The model's route (2.5 m, 3.5 m, ... ahead along a left circle of ``radius`` centred at (0, radius)),
    seen from the rear axle ``pose``."""
    theta0 = math.atan2(pose[0], radius - pose[1])
    theta = theta0 + (2.5 + np.arange(10)) / radius
    world = np.column_stack([radius * np.sin(theta), radius - radius * np.cos(theta)])
    return points_to_local(world, pose)


def test_lateral_pid_follows_a_15m_left_turn_at_8mps_within_half_a_metre():
    radius, speed = 15.0, 8.0
    pose = np.zeros(3)  # rear axle on the circle, heading along it
    controller = LateralPID()
    worst, turned = 0.0, 0.0
    for _ in range(120):  # 6 s: 48 m, about 3/4 of the circle
        steer = controller.step(circle_route(pose, radius), speed)
        wheel = -steer * MAX_WHEEL_ANGLE  # CARLA steer is positive to the right
        yaw_rate = speed * math.tan(wheel) / WHEEL_BASE
        pose = pose + DT * np.array([speed * math.cos(pose[2]), speed * math.sin(pose[2]), yaw_rate])
        turned += yaw_rate * DT
        worst = max(worst, abs(math.hypot(pose[0], pose[1] - radius) - radius))
    assert turned > 3.0  # it really went round the bend, to the left
    assert worst < 0.5


def test_lookahead_grows_with_speed():
    # v = 28.8 km/h: 0.9755 * 28.8 + 1.915 = 30.01 -> 3.001 - 2 -> point 1; standstill: 24 / 10 - 2 -> 0
    assert lookahead_index(8.0, 10) == 1
    assert lookahead_index(0.0, 10) == 0
    assert lookahead_index(30.0, 10) == 8  # 0.9755 * 108 + 1.9 = 107 -> 105 -> 8.5
    assert lookahead_index(8.0, 10, curvature=0.6) == 3  # int(0.6 * 3.5) = 2 points further


def test_target_speed_zero_brakes():
    assert throttle_brake(0.0, 5.0) == (0.0, 1.0)
    assert throttle_brake(0.0, 0.0) == (0.0, 1.0)


def test_a_target_ten_percent_below_the_speed_brakes():
    assert throttle_brake(9.0, 10.0) == (0.0, 1.0)  # 10 / 9 = 1.11 > 1.1
    throttle, brake = throttle_brake(9.5, 10.0)  # 1.053 < 1.1, but above 1.0313: the regression's own brake
    assert (throttle, brake) == (0.0, 1.0)
    assert throttle_brake(10.0, 5.0) == (1.0, 0.0)  # 18 km/h short of the target: full throttle


def test_throttle_regression_by_hand():
    # target 10 m/s = 36 km/h, speed 35.9 km/h: e = 0.1 / 100, v = 0.359
    v, e = 0.359, 0.001
    params = (1.1990342347353184, -0.8057602384167799, 1.710818710950062, 0.921890257450335, 1.556497522998393)
    expected = params[0] * v + params[1] * v * v + params[2] * 100 * e + params[3] * e * e + params[4] * v * e
    expected += -0.7013479734904027 * v * v * e
    throttle, brake = throttle_brake(10.0, 35.9 / 3.6)
    assert 0.4 < expected < 0.6
    assert brake == 0.0 and throttle == pytest.approx(expected)


def test_target_speed_decoding():
    classes = (0.0, 4.0, 8.0, 10.0, 13.89, 16.0, 17.78, 20.0)
    assert decode_target_speed(np.array([-50, -50, 10.0, 10.0, -50, -50, -50, -50]), classes) == pytest.approx(9.0)
    assert decode_target_speed(np.array([5.0, 0, 0, 0, 0, 0, 0, 0]), classes) == 0.0  # P(stop) = 0.955 > 0.9


def test_pid_window_starts_with_zeros():
    pid = PIDController(1.0, 2.0, 3.0, 4)
    assert pid.step(1.0) == pytest.approx(1.0 + 2.0 * 0.25 + 3.0 * 1.0)
    assert pid.step(1.0) == pytest.approx(1.0 + 2.0 * 0.5 + 0.0)


def test_waypoint_controller_turns_left_and_brakes_for_a_stop():
    controller = WaypointController(dt=0.25)
    t = np.arange(1, 9) * 0.25
    left = np.column_stack([6.0 * t, 0.3 * t**2])
    control = controller.step(left, speed=5.0)
    assert control.steer < 0 and control.brake == 0.0 and control.throttle > 0
    stop = np.zeros((8, 2))
    assert controller.step(stop, speed=5.0).brake == 1.0


def test_gating_stops_throttle_and_standing_steer():
    assert gate(Control(0.3, 0.5, 1.0), speed=0.0) == Control(0.0, 0.0, 1.0)
    assert gate(Control(0.3, 0.5, 1.0), speed=3.0) == Control(0.3, 0.0, 1.0)
    assert gate(Control(0.3, 0.5, 0.0), speed=0.0) == Control(0.3, 0.5, 0.0)


def test_creeping_after_55_seconds_unless_blocked():
    creeper = Creeper(front_bumper_x=2.4508 + 1.389, half_width=1.0642)
    hold = Control(0.0, 0.0, 1.0)
    for _ in range(1100):
        assert creeper.step(hold, 0.0, None) == hold
    assert creeper.step(hold, 0.0, None) == Control(0.0, 0.4, 0.0)  # frame 1101: forced move
    blocker = np.array([[4.5, 0.0, 1.0]])  # 0.66 m ahead of the bumper, at bumper height
    assert creeper.step(hold, 0.0, blocker) == Control(0.0, 0.0, 1.0)
    for _ in range(20):
        assert creeper.step(hold, 0.0, None).throttle == 0.4
    assert creeper.step(hold, 0.0, None) == hold  # the 20 frames are used up


def test_stop_sign_brakes_until_stopped_then_clears():
    heuristic = StopSignSlowdown()
    go = Control(0.0, 0.8, 0.0)
    assert heuristic.step(go, 3.0, 0.5) == Control(0.0, 0.0, 1.0)
    assert heuristic.step(go, 0.0, 0.5) == go  # stopped: cleared
    assert heuristic.step(go, 2.0, 0.5).throttle == pytest.approx(0.1)  # cleared, but slowed for 40 frames
    for _ in range(39):
        assert heuristic.step(go, 2.0, None).throttle == pytest.approx(0.1)
    assert heuristic.step(go, 2.0, None) == go  # the 40 frames are used up
    assert StopSignSlowdown().step(go, 3.0, 5.0) == go
