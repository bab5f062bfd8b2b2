"""One Euler step of NAVSIM's batched kinematic bicycle (``pdm_planner/simulation/batch_kinematic_bicycle.py``).

Reference point: the rear axle. The commanded acceleration and steering rate pass through first-order lags
(``dt / (dt + tau)`` blends, tau 0.2 s for acceleration and 0.05 s for the steering angle) before integration.
Behaviours reproduced on purpose:

- the pose and the heading rate use the *current* steering angle and speed (the lagged commands only change
  the speed and the steering angle of the next state);
- the steering angle is clipped to +-pi/3 but the stored steering rate is the unclipped lagged rate;
- vy and ay are 0 after the first step; the angular velocity is ``v' tan(delta') / L`` of the new state and the
  angular acceleration its finite difference over the step;
- the heading is wrapped to [-pi, pi) (nuPlan ``principal_value``).
"""

from typing import NamedTuple

import numpy as np

MAX_STEERING_ANGLE = np.pi / 3
ACCEL_TIME_CONSTANT = 0.2
STEERING_ANGLE_TIME_CONSTANT = 0.05


class BicycleState(NamedTuple):
    """The ego states of all proposals at one time, one ``(N,)`` array per quantity (vy = ay = 0 after t0)."""

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    steering: np.ndarray
    steering_rate: np.ndarray
    yaw_rate: np.ndarray
    yaw_accel: np.ndarray


def heading_rate(state: BicycleState, wheel_base: float) -> np.ndarray:
    """``v tan(delta) / L``: the state's yaw rate, except at t0 where NAVSIM stores 0 but still turns at this rate."""
    return state.speed * np.tan(state.steering) / wheel_base


def propagate(
    state: BicycleState,
    turn_rate: np.ndarray,
    accel_cmd: np.ndarray,
    steering_rate_cmd: np.ndarray,
    dt: float,
    wheel_base: float,
) -> BicycleState:
    """The state after ``dt`` seconds under commanded acceleration and steering rate ``(N,)``.

    ``turn_rate`` is ``heading_rate(state)`` (the previous step's ``yaw_rate``, computed the same way).
    """
    speed, steering, accel = state.speed, state.steering, state.accel
    lagged_accel = dt / (dt + ACCEL_TIME_CONSTANT) * (accel_cmd - accel) + accel
    ideal_steering = dt * steering_rate_cmd + steering
    lagged_steering = dt / (dt + STEERING_ANGLE_TIME_CONSTANT) * (ideal_steering - steering) + steering
    lagged_rate = (lagged_steering - steering) / dt

    new_heading = state.heading + turn_rate * dt
    new_speed = speed + lagged_accel * dt
    new_steering = np.minimum(np.maximum(steering + lagged_rate * dt, -MAX_STEERING_ANGLE), MAX_STEERING_ANGLE)
    new_yaw_rate = new_speed * np.tan(new_steering) / wheel_base
    return BicycleState(
        x=state.x + speed * np.cos(state.heading) * dt,
        y=state.y + speed * np.sin(state.heading) * dt,
        heading=(new_heading + np.pi) % (2 * np.pi) - np.pi,
        speed=new_speed,
        accel=lagged_accel,
        steering=new_steering,
        steering_rate=lagged_rate,
        yaw_rate=new_yaw_rate,
        yaw_accel=(new_yaw_rate - state.yaw_rate) / dt,
    )
