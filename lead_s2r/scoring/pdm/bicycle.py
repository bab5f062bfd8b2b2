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

import math
from typing import NamedTuple

from numba import njit

MAX_STEERING_ANGLE = math.pi / 3
ACCEL_TIME_CONSTANT = 0.2
STEERING_ANGLE_TIME_CONSTANT = 0.05


class BicycleState(NamedTuple):
    """One proposal's ego state at one time; vy = ay = 0 after t0."""

    x: float
    y: float
    heading: float
    speed: float
    accel: float
    steering: float
    steering_rate: float
    yaw_rate: float
    yaw_accel: float


class BicycleConstants(NamedTuple):
    """The model's constants for one step length."""

    dt: float
    accel_lag: float
    steering_lag: float
    wheel_base: float


def bicycle_constants(dt: float, wheel_base: float) -> BicycleConstants:
    """Constants for stepping by ``dt`` seconds; the lags are ``dt / (dt + tau)`` blends."""
    return BicycleConstants(dt, dt / (dt + ACCEL_TIME_CONSTANT), dt / (dt + STEERING_ANGLE_TIME_CONSTANT), wheel_base)


@njit(cache=True)
def heading_rate(state: BicycleState, wheel_base: float) -> float:
    """``v tan(delta) / L``: the state's yaw rate, except at t0 where NAVSIM stores 0 but still turns at this rate."""
    return state.speed * math.tan(state.steering) / wheel_base


@njit(cache=True)
def propagate(
    state: BicycleState, turn_rate: float, accel_cmd: float, steering_rate_cmd: float, const: BicycleConstants
) -> BicycleState:
    """The state after ``const.dt`` seconds under commanded acceleration and steering rate; ``turn_rate`` is
    ``heading_rate(state)`` (the previous step's ``yaw_rate``, computed the same way)."""
    dt, speed, steering, accel, heading = const.dt, state.speed, state.steering, state.accel, state.heading
    lagged_accel = const.accel_lag * (accel_cmd - accel) + accel
    ideal_steering = dt * steering_rate_cmd + steering
    lagged_steering = const.steering_lag * (ideal_steering - steering) + steering
    lagged_rate = (lagged_steering - steering) / dt

    new_speed = speed + lagged_accel * dt
    new_steering = min(max(steering + lagged_rate * dt, -MAX_STEERING_ANGLE), MAX_STEERING_ANGLE)
    new_yaw_rate = new_speed * math.tan(new_steering) / const.wheel_base
    return BicycleState(
        state.x + speed * math.cos(heading) * dt,
        state.y + speed * math.sin(heading) * dt,
        (heading + turn_rate * dt + math.pi) % (2 * math.pi) - math.pi,
        new_speed,
        lagged_accel,
        new_steering,
        lagged_rate,
        new_yaw_rate,
        (new_yaw_rate - state.yaw_rate) / dt,
    )
