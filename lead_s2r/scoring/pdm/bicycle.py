"""One Euler step of NAVSIM's batched kinematic bicycle (``pdm_planner/simulation/batch_kinematic_bicycle.py``).

Reference point: the rear axle. The commanded acceleration and steering rate pass through first-order lags
(``dt / (dt + tau)`` blends, tau 0.2 s for acceleration and 0.05 s for the steering angle) before integration.
Behaviours reproduced on purpose:

- the pose and the heading rate use the *current* steering angle and speed (the lagged commands only change
  the speed and the steering angle of the next state);
- the steering angle is clipped to +-pi/3 but the stored steering rate is the unclipped lagged rate;
- vy and ay are 0 after the first step; the angular velocity is ``v' tan(delta') / L`` of the new state and the
  angular acceleration its finite difference over the step;
- the heading is wrapped to [-pi, pi) (nuPlan ``principal_value``);
- the initial state stores yaw rate 0 whatever its steering angle, yet the first step turns at
  ``v tan(delta) / L`` and the first yaw acceleration is the new yaw rate over dt (``heading_rate``).
"""

from typing import NamedTuple

import numpy as np

from lead_s2r.scoring.pdm.elementwise import Elementwise, Values

MAX_STEERING_ANGLE = np.pi / 3
ACCEL_TIME_CONSTANT = 0.2
STEERING_ANGLE_TIME_CONSTANT = 0.05


class BicycleState(NamedTuple):
    """The ego states of all proposals at one time, one ``(N,)`` array (or one proposal's float) per quantity;
    vy = ay = 0 after t0."""

    x: Values
    y: Values
    heading: Values
    speed: Values
    accel: Values
    steering: Values
    steering_rate: Values
    yaw_rate: Values
    yaw_accel: Values


class BicycleConstants(NamedTuple):
    """The model's constants, as ``(N,)`` rows (numpy multiplies two arrays faster than a float and an array) or
    as floats for one proposal."""

    dt: Values
    accel_lag: Values
    steering_lag: Values
    wheel_base: Values
    max_steering: Values
    min_steering: Values
    pi: Values
    two_pi: Values


def bicycle_constants(dt: float, wheel_base: float, count: int | None = None) -> BicycleConstants:
    """Constants for stepping by ``dt`` seconds, as rows for ``count`` proposals or floats (None); the lags are
    ``dt / (dt + tau)`` blends."""
    values = (
        dt,
        dt / (dt + ACCEL_TIME_CONSTANT),
        dt / (dt + STEERING_ANGLE_TIME_CONSTANT),
        wheel_base,
        MAX_STEERING_ANGLE,
        -MAX_STEERING_ANGLE,
        np.pi,
        2 * np.pi,
    )
    if count is None:
        return BicycleConstants(*values)
    return BicycleConstants(*(np.full(count, value) for value in values))


def heading_rate(state: BicycleState, wheel_base: float, ops: Elementwise) -> Values:
    """``v tan(delta) / L``: the state's yaw rate, except at t0 where NAVSIM stores 0 but still turns at this rate."""
    return state.speed * ops.tan(state.steering) / wheel_base


def propagate(
    state: BicycleState,
    turn_rate: Values,
    accel_cmd: Values,
    steering_rate_cmd: Values,
    const: BicycleConstants,
    ops: Elementwise,
) -> BicycleState:
    """The state after ``const.dt`` seconds under commanded acceleration and steering rate.

    ``turn_rate`` is ``heading_rate(state)`` (the previous step's ``yaw_rate``, computed the same way).
    """
    dt, speed, steering, accel, heading = const.dt, state.speed, state.steering, state.accel, state.heading
    lagged_accel = const.accel_lag * (accel_cmd - accel) + accel
    ideal_steering = dt * steering_rate_cmd + steering
    lagged_steering = const.steering_lag * (ideal_steering - steering) + steering
    lagged_rate = (lagged_steering - steering) / dt

    new_speed = speed + lagged_accel * dt
    new_steering = ops.minimum(ops.maximum(steering + lagged_rate * dt, const.min_steering), const.max_steering)
    new_yaw_rate = new_speed * ops.tan(new_steering) / const.wheel_base
    return BicycleState(
        x=state.x + speed * ops.cos(heading) * dt,
        y=state.y + speed * ops.sin(heading) * dt,
        heading=(heading + turn_rate * dt + const.pi) % const.two_pi - const.pi,
        speed=new_speed,
        accel=lagged_accel,
        steering=new_steering,
        steering_rate=lagged_rate,
        yaw_rate=new_yaw_rate,
        yaw_accel=(new_yaw_rate - state.yaw_rate) / dt,
    )
