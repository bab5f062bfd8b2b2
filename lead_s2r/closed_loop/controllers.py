"""Predictions -> steer / throttle / brake, as LEAD's closed-loop inference does it (``pid_controller.py``,
``closed_loop_inference.py``); every constant is LEAD's, named. Facts: ``docs/closed_loop.md``.

Everything here works in the ISO ego frame (y left, positive angles turn left) and converts to CARLA's steer sign
(positive = right) only in the returned :class:`Control`. LEAD's route is in its vehicle-centre frame, ours starts
at the rear axle: the heading error is measured from the rear axle, the point a kinematic bicycle turns about.
"""

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

#: LEAD's ``brake_ratio``: brake when the ego is this much faster than the target speed.
BRAKE_RATIO = 1.1
#: Below this target speed (m/s) the longitudinal controller brakes.
STOP_TARGET_SPEED = 0.01
#: A moving target is raised to at least 1 km/h.
MIN_TARGET_SPEED = 1.0 / 3.6
#: ``longitudinal_max_accelerations``: a speed error above this (km/h) is full throttle.
FULL_THROTTLE_ERROR_KMH = 1.89
#: The expert's linear-regression throttle: weights of [v, v^2, 100 e, e^2, v e, v^2 e] (v, e in km/h / 100) and
#: the speed/target ratio above which it brakes (``params[0:6]``, ``params[6]``).
THROTTLE_PARAMS = (
    1.1990342347353184,
    -0.8057602384167799,
    1.710818710950062,
    0.921890257450335,
    1.556497522998393,
    -0.7013479734904027,
)
THROTTLE_BRAKE_RATIO = 1.031266635497984
#: Lateral PID on the route (``LateralPIDController``): gains, error window.
LATERAL_KP, LATERAL_KD, LATERAL_KI = 3.118357247806046, 1.3782508892109167, 0.6406067986034124
LATERAL_WINDOW = 6
#: Speed-dependent look-ahead: ``clip(slope * v_kmh + offset, low, high) / 10 - 2`` route points.
LOOKAHEAD_SLOPE, LOOKAHEAD_OFFSET = 0.9755321901954155, 1.9152884533402488
LOOKAHEAD_LOW, LOOKAHEAD_HIGH = 24.0, 105.0
#: ``sensor_agent_steer_correction``: look ``clip(int(curvature * gain), 0, max)`` points further on curved routes.
CURVATURE_GAIN, MAX_CURVATURE_SHIFT = 3.5, 2
#: LEAD's two-hot target-speed decoding: a stop when P(slowest class) exceeds this.
BRAKE_PROBABILITY = 0.9
#: Waypoint controller (modality "waypoint"): PID gains (kp, ki, kd, window) for speed and heading.
SPEED_PID = (1.75, 1.0, 2.0, 20)
TURN_PID = (1.25, 0.75, 0.3, 20)
MAX_SPEED_DELTA = 0.99
WAYPOINT_STOP_SPEED = 0.4
#: Aim distance (m): short below ``AIM_SPEED_SWITCH`` m/s, long above.
AIM_NEAR, AIM_FAR, AIM_SPEED_SWITCH = 2.25, 3.0, 5.5
#: Below this ego speed (m/s) the ego counts as standing: no steering while braking.
STANDSTILL_SPEED = 0.01
#: Creeping (``sensor_agent_creeping``): frames below ``STUCK_SPEED`` before forcing a move of ``CREEP_FRAMES``
#: frames at ``CREEP_THROTTLE`` unless LiDAR points fill the box ahead (x beyond the bumper by ``CREEP_BOX_LENGTH``,
#: |y| under ``CREEP_BOX_WIDTH_SHARE`` of the half width, z in ``CREEP_BOX_Z``).
STUCK_SPEED, STUCK_FRAMES, CREEP_FRAMES, CREEP_THROTTLE = 0.1, 1100, 20, 0.4
CREEP_BOX_LENGTH, CREEP_BOX_WIDTH_SHARE, CREEP_BOX_Z = 2.5, 0.8, (0.5, 1.5)
#: Stop-sign slow-down (``slower_for_stop_sign``): distance (m), frames of throttle limit, cooldowns (frames).
STOP_SIGN_DISTANCE, STOP_SIGN_SLOW_FRAMES, STOP_SIGN_COOLDOWN, STOP_SIGN_MAX_THROTTLE = 1.0, 40, 120, 0.1


@dataclass(frozen=True)
class Control:
    """One actuation in CARLA's convention: steer in [-1, 1] (positive = right), throttle and brake in [0, 1]."""

    steer: float
    throttle: float
    brake: float


def heading_error(point: np.ndarray) -> float:
    """Angle of an ego-frame point from the x axis, in LEAD's unit (degrees / 90; positive = left)."""
    return math.degrees(math.atan2(float(point[1]), float(point[0]))) / 90.0


def route_curvature(route: np.ndarray) -> float:
    """Mean absolute heading change per metre along a polyline (1/m)."""
    steps = np.diff(np.asarray(route, np.float64), axis=0)
    lengths = np.linalg.norm(steps, axis=1)
    if len(steps) < 2 or lengths.sum() <= 0:
        return 0.0
    angles = np.unwrap(np.arctan2(steps[:, 1], steps[:, 0]))
    return float(np.abs(np.diff(angles)).sum() / lengths[1:].sum())


def lookahead_index(speed: float, count: int, curvature: float = 0.0, correct: bool = True) -> int:
    """Route point the lateral controller aims at, for an ego at ``speed`` m/s on a route of ``count`` points."""
    kmh = speed * 3.6
    points = np.clip(LOOKAHEAD_SLOPE * kmh + LOOKAHEAD_OFFSET, LOOKAHEAD_LOW, LOOKAHEAD_HIGH) / 10 - 2
    index = int(min(points, count - 1))
    if correct:
        index += int(np.clip(int(curvature * CURVATURE_GAIN), 0, MAX_CURVATURE_SHIFT))
    return min(index, count - 1)


class LateralPID:
    """LEAD's lateral PID on the predicted route (ego-frame points 1 m apart): the heading error towards a
    speed-dependent look-ahead point, P + D (last difference) + I (mean over the last 6 errors)."""

    def __init__(self, steer_correction: bool = True) -> None:
        self.steer_correction = steer_correction
        self.errors: deque[float] = deque(maxlen=LATERAL_WINDOW)

    def step(self, route: np.ndarray, speed: float) -> float:
        """CARLA steer (positive = right) for an ISO-frame ``route`` (K, 2) at ``speed`` m/s."""
        route = np.asarray(route, np.float64)
        index = lookahead_index(speed, len(route), route_curvature(route), self.steer_correction)
        self.errors.append(heading_error(route[index]))
        derivative = self.errors[-1] - self.errors[-2] if len(self.errors) > 1 else 0.0
        integral = float(np.mean(self.errors))
        left = LATERAL_KP * self.errors[-1] + LATERAL_KD * derivative + LATERAL_KI * integral
        return round(float(np.clip(-left, -1.0, 1.0)), 3)


def throttle_brake(target_speed: float, speed: float) -> tuple[float, float]:
    """LEAD's longitudinal model (the expert's linear regression) on a target speed, both m/s: (throttle, brake)."""
    if target_speed < STOP_TARGET_SPEED or speed / target_speed > BRAKE_RATIO:
        return 0.0, 1.0
    target_kmh, speed_kmh = max(target_speed, MIN_TARGET_SPEED) * 3.6, speed * 3.6
    error = target_kmh - speed_kmh
    if error > FULL_THROTTLE_ERROR_KMH:
        return 1.0, 0.0
    if speed_kmh / target_kmh > THROTTLE_BRAKE_RATIO:
        return 0.0, 1.0
    v, e = speed_kmh / 100.0, max(error, 0.0) / 100.0
    features = np.array([v, v * v, 100.0 * e, e * e, v * e, v * v * e])
    return float(np.clip(features @ np.array(THROTTLE_PARAMS), 0.0, 1.0)), 0.0


def decode_target_speed(logits: np.ndarray, classes: tuple[float, ...]) -> float:
    """Expected speed of the softmax over the speed classes (two-hot decoding), 0 when P(stop class) > 0.9."""
    logits = np.asarray(logits, np.float64)
    probabilities = np.exp(logits - logits.max())
    probabilities /= probabilities.sum()
    if probabilities[0] > BRAKE_PROBABILITY:
        return 0.0
    return float(probabilities @ np.asarray(classes, np.float64))


class PIDController:
    """LEAD's ``PIDController``: a window of the last ``n`` errors pre-filled with zeros; I = its mean, D = the last."""

    def __init__(self, kp: float, ki: float, kd: float, n: int) -> None:
        self.kp, self.ki, self.kd = kp, ki, kd
        self.window: deque[float] = deque([0.0] * n, maxlen=n)

    def step(self, error: float) -> float:
        self.window.append(error)
        derivative = self.window[-1] - self.window[-2]
        return self.kp * error + self.ki * float(np.mean(self.window)) + self.kd * derivative


class WaypointController:
    """LEAD's waypoint controller: speed from the 0.5 s -> 1.0 s displacement of the predicted waypoints, steer
    towards the first waypoint beyond the aim distance."""

    def __init__(self, dt: float) -> None:
        self.near, self.far = round(0.5 / dt) - 1, round(1.0 / dt) - 1  # indices of t = 0.5 s and 1.0 s
        self.span = (self.far - self.near) * dt
        if self.near < 0:
            raise ValueError(f"waypoint controller needs waypoints at 0.5 s and 1 s; the grid's step is {dt} s")
        self.speed_pid = PIDController(*SPEED_PID)
        self.turn_pid = PIDController(*TURN_PID)

    def step(self, waypoints: np.ndarray, speed: float) -> Control:
        waypoints = np.asarray(waypoints, np.float64)
        desired = float(np.linalg.norm(waypoints[self.near] - waypoints[self.far])) / self.span
        brake = desired < WAYPOINT_STOP_SPEED or (desired > 0 and speed / desired > BRAKE_RATIO)
        delta = float(np.clip(desired - speed, 0.0, MAX_SPEED_DELTA))
        throttle = float(np.clip(self.speed_pid.step(delta), 0.0, 1.0))  # the PID steps while braking too
        throttle = 0.0 if brake else throttle
        aim_distance = AIM_NEAR if desired < AIM_SPEED_SWITCH else AIM_FAR
        far_enough = np.flatnonzero(np.linalg.norm(waypoints, axis=1) >= aim_distance)
        aim = waypoints[far_enough[0] if len(far_enough) else -1]
        angle = 0.0 if speed < STANDSTILL_SPEED or brake else heading_error(aim)
        steer = float(np.clip(-self.turn_pid.step(angle), -1.0, 1.0))
        return Control(steer, throttle, float(brake))


def gate(control: Control, speed: float) -> Control:
    """LEAD's final gating: no throttle while braking, and no steering while braking at a standstill."""
    if control.brake <= 0:
        return control
    steer = 0.0 if speed < STANDSTILL_SPEED else control.steer
    return Control(steer, 0.0, control.brake)


class Creeper:
    """Creeping when stuck: after 1100 frames (55 s at 20 Hz) below 0.1 m/s, force 20 frames of throttle unless
    LiDAR points (ISO rear-axle frame) lie in the box ahead of the bumper, which restarts the 20 frames."""

    def __init__(self, front_bumper_x: float, half_width: float) -> None:
        self.box_x = (front_bumper_x, front_bumper_x + CREEP_BOX_LENGTH)
        self.box_y = CREEP_BOX_WIDTH_SHARE * half_width
        self.stuck_frames, self.force_frames = 0, 0

    def obstructed(self, points: np.ndarray | None) -> bool:
        if points is None or not len(points):
            return False
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        inside = (x > self.box_x[0]) & (x < self.box_x[1]) & (np.abs(y) < self.box_y)
        return bool((inside & (z > CREEP_BOX_Z[0]) & (z < CREEP_BOX_Z[1])).any())

    def step(self, control: Control, speed: float, points: np.ndarray | None) -> Control:
        self.stuck_frames = self.stuck_frames + 1 if speed < STUCK_SPEED else 0
        if self.stuck_frames > STUCK_FRAMES:
            self.force_frames, self.stuck_frames = CREEP_FRAMES, 0
        if self.force_frames <= 0:
            return control
        if self.obstructed(points):
            self.force_frames = CREEP_FRAMES
            return Control(control.steer, 0.0, 1.0)
        self.force_frames -= 1
        return Control(control.steer, max(CREEP_THROTTLE, control.throttle), 0.0)


class StopSignSlowdown:
    """Stop-sign heuristic on the distance (m) to the nearest predicted stop sign: within 1 m, brake until stopped
    (then the sign counts as cleared for 120 frames), else limit the throttle to 0.1 for 40 frames (cooldown 120).
    LEAD uses the same 1 m threshold in both branches; so does this."""

    def __init__(self) -> None:
        self.clear_cooldown, self.slow_cooldown, self.slow_frames = 0, 0, 0

    def step(self, control: Control, speed: float, distance: float | None) -> Control:
        self.clear_cooldown -= 1
        self.slow_cooldown -= 1
        near = distance is not None and distance < STOP_SIGN_DISTANCE
        if near and self.clear_cooldown <= 0:
            if speed > STANDSTILL_SPEED:
                return Control(control.steer, 0.0, 1.0)
            self.clear_cooldown = STOP_SIGN_COOLDOWN
        elif near and self.slow_cooldown <= 0:
            self.slow_frames, self.slow_cooldown = STOP_SIGN_SLOW_FRAMES, STOP_SIGN_COOLDOWN
        if self.slow_frames > 0:
            self.slow_frames -= 1
            return Control(control.steer, min(control.throttle, STOP_SIGN_MAX_THROTTLE), control.brake)
        return control
