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

import numpy as np

from lead_s2r.scoring.pdm.state import StateIndex as S
from lead_s2r.scoring.pdm.vehicle import VehicleParameters

MAX_STEERING_ANGLE = np.pi / 3
ACCEL_TIME_CONSTANT = 0.2
STEERING_ANGLE_TIME_CONSTANT = 0.05


def propagate(
    states: np.ndarray, accel_cmd: np.ndarray, steering_rate_cmd: np.ndarray, dt: float, vehicle: VehicleParameters
) -> np.ndarray:
    """States ``(N, 11)`` after ``dt`` seconds under commanded acceleration and steering rate ``(N,)``."""
    speed, heading, steering = states[:, S.VELOCITY_X], states[:, S.HEADING], states[:, S.STEERING_ANGLE]
    accel = states[:, S.ACCELERATION_X]
    lagged_accel = dt / (dt + ACCEL_TIME_CONSTANT) * (accel_cmd - accel) + accel
    ideal_steering = dt * steering_rate_cmd + steering
    lagged_steering = dt / (dt + STEERING_ANGLE_TIME_CONSTANT) * (ideal_steering - steering) + steering
    lagged_rate = (lagged_steering - steering) / dt

    out = np.empty_like(states)
    out[:, S.X] = states[:, S.X] + speed * np.cos(heading) * dt
    out[:, S.Y] = states[:, S.Y] + speed * np.sin(heading) * dt
    new_heading = heading + speed * np.tan(steering) / vehicle.wheel_base * dt
    out[:, S.HEADING] = (new_heading + np.pi) % (2 * np.pi) - np.pi
    out[:, S.VELOCITY_X] = speed + lagged_accel * dt
    out[:, S.VELOCITY_Y] = 0.0
    out[:, S.ACCELERATION_X] = lagged_accel
    out[:, S.ACCELERATION_Y] = 0.0
    out[:, S.STEERING_ANGLE] = np.clip(steering + lagged_rate * dt, -MAX_STEERING_ANGLE, MAX_STEERING_ANGLE)
    out[:, S.STEERING_RATE] = lagged_rate
    out[:, S.ANGULAR_VELOCITY] = out[:, S.VELOCITY_X] * np.tan(out[:, S.STEERING_ANGLE]) / vehicle.wheel_base
    out[:, S.ANGULAR_ACCELERATION] = (out[:, S.ANGULAR_VELOCITY] - states[:, S.ANGULAR_VELOCITY]) / dt
    return out
