"""NAVSIM's ``PDMSimulator.simulate_proposals``: 40 steps of LQR tracking + kinematic bicycle, batched over proposals.

The simulation starts from the logged ego state at t0 (rear axle, ego frame, so x = y = heading = 0): speed and
acceleration as logged (vy and ay included, in the body frame), the tire steering angle as given (NAVSIM: 0),
steering rate, yaw rate and yaw acceleration 0. Each step the tracker (``lqr.py``) turns the 41 targets from
``interpolation.py`` into commands and the bicycle (``bicycle.py``) applies them. Targets carry only poses: NAVSIM
gives the agent's states zero velocity and acceleration and the tracker never reads them.

The result equals the official one to ~1e-9 (``tests/test_pdm_simulation.py`` against the v1.1 and v2.2 golden
files), in the ego frame instead of the global frame: every step is invariant to a rigid motion of the scene.
"""

import numpy as np

from lead_s2r.scoring.pdm.bicycle import propagate
from lead_s2r.scoring.pdm.interpolation import PROPOSAL_INTERVAL
from lead_s2r.scoring.pdm.lqr import reference_profiles, track
from lead_s2r.scoring.pdm.state import STATE_SIZE
from lead_s2r.scoring.pdm.state import StateIndex as S
from lead_s2r.scoring.pdm.vehicle import PACIFICA, VehicleParameters

#: nuPlan steps the bicycle by ``TimeDuration.from_s(0.1).time_s`` = 100000 us * 1e-6 (0.09999999999999999).
SIMULATION_DT = int(PROPOSAL_INTERVAL * 1e6) * 1e-6


def initial_state(
    ego_velocity: np.ndarray, ego_acceleration: np.ndarray, tire_steering_angle: float = 0.0
) -> np.ndarray:
    """The ``(11,)`` state at t0 in the ego frame, as ``ego_state_to_state_array`` fills it."""
    state = np.zeros(STATE_SIZE)
    state[S.VELOCITY_X : S.VELOCITY_Y + 1] = ego_velocity
    state[S.ACCELERATION_X : S.ACCELERATION_Y + 1] = ego_acceleration
    state[S.STEERING_ANGLE] = tire_steering_angle
    return state


def simulate_proposals(
    targets: np.ndarray,
    ego_velocity: np.ndarray,
    ego_acceleration: np.ndarray,
    tire_steering_angle: float = 0.0,
    vehicle: VehicleParameters = PACIFICA,
) -> np.ndarray:
    """Targets ``(N, T, 3)`` (T = 41: t = 0..4 s every 0.1 s, ego frame) -> simulated states ``(N, T, 11)``."""
    targets = np.asarray(targets, np.float64)
    if targets.ndim != 3 or targets.shape[-1] != 3 or targets.shape[1] < 4:
        raise ValueError(f"targets: expected shape (N, T >= 4, 3) of x, y, heading every 0.1 s, got {targets.shape}")
    count, num_states, _ = targets.shape
    profiles = reference_profiles(targets, PROPOSAL_INTERVAL)
    states = np.empty((count, num_states, STATE_SIZE))
    states[:, 0] = initial_state(np.asarray(ego_velocity), np.asarray(ego_acceleration), tire_steering_angle)
    for step in range(num_states - 1):
        accel, steering_rate = track(states[:, step], targets, profiles, step, PROPOSAL_INTERVAL, vehicle.wheel_base)
        states[:, step + 1] = propagate(states[:, step], accel, steering_rate, SIMULATION_DT, vehicle)
    return states
