"""NAVSIM's ``PDMSimulator.simulate_proposals``: 40 steps of LQR tracking + kinematic bicycle, batched over proposals.

The simulation starts from the logged ego state at t0 (rear axle, ego frame, so x = y = heading = 0): speed and
acceleration as logged (vy and ay included, in the body frame), the tire steering angle as given (NAVSIM: 0),
steering rate, yaw rate and yaw acceleration 0. Each step the tracker (``lqr.py``) turns the 41 targets from
``interpolation.py`` into commands and the bicycle (``bicycle.py``) applies them. Targets carry only poses: NAVSIM
gives the agent's states zero velocity and acceleration and the tracker never reads them.

The result equals the official one within the 1e-6 rounding of the golden files (``tests/test_pdm_simulation.py``, every
trajectory of the v1.1 and v2.2 files), in the ego frame instead of the global frame: every step is invariant to a rigid
motion of the scene. The 40 steps are sequential and each is ~80 scalar operations per proposal, which numpy would spend
~0.5 us apiece on, so they run compiled (numba), one proposal after another; the fits that feed them
(``tracking_reference``) stay vectorised over proposals. Costs: ``benchmarks/pdm_simulation.py``.
"""

import numpy as np
from numba import njit

from lead_s2r.scoring.pdm.bicycle import BicycleConstants, BicycleState, bicycle_constants, heading_rate, propagate
from lead_s2r.scoring.pdm.interpolation import PROPOSAL_INTERVAL
from lead_s2r.scoring.pdm.lqr import LateralTerms, TrackingReference, track, tracking_reference
from lead_s2r.scoring.pdm.state import STATE_SIZE, StateIndex
from lead_s2r.scoring.pdm.vehicle import PACIFICA, VehicleParameters

#: nuPlan steps the bicycle by ``TimeDuration.from_s(0.1).time_s`` = 100000 us * 1e-6 (0.09999999999999999).
SIMULATION_DT = int(PROPOSAL_INTERVAL * 1e6) * 1e-6


def initial_state(
    ego_velocity: np.ndarray, ego_acceleration: np.ndarray, tire_steering_angle: float = 0.0
) -> np.ndarray:
    """The ``(11,)`` state at t0 in the ego frame, as ``ego_state_to_state_array`` fills it."""
    for name, value in (("ego_velocity", ego_velocity), ("ego_acceleration", ego_acceleration)):
        if np.shape(value) != (2,) or not np.isfinite(value).all():
            raise ValueError(f"{name}: expected 2 finite numbers (x, y in the ego body frame), got {value!r}")
    state = np.zeros(STATE_SIZE)
    state[StateIndex.VELOCITY_X : StateIndex.VELOCITY_Y + 1] = ego_velocity
    state[StateIndex.ACCELERATION_X : StateIndex.ACCELERATION_Y + 1] = ego_acceleration
    state[StateIndex.STEERING_ANGLE] = tire_steering_angle
    return state


@njit(cache=True)
def _simulate(
    reference: TrackingReference, terms: LateralTerms, start: BicycleState, constants: BicycleConstants,
    states: np.ndarray,
) -> None:  # fmt: skip
    """Steps every proposal from ``start`` through its targets, writing the bicycle's columns of ``states[:, 1:]``,
    one proposal at a time: a row's bits are its own, whatever rows come with it."""
    count, num_steps = reference.speed.shape
    for n in range(count):
        state = start
        turn_rate = heading_rate(state, constants.wheel_base)
        for s in range(num_steps):
            accel, steering_rate = track(
                reference, n, s, state.x, state.y, state.heading, state.speed, state.steering, terms
            )
            state = propagate(state, turn_rate, accel, steering_rate, constants)
            turn_rate = state.yaw_rate
            row = states[n, s + 1]
            row[StateIndex.X], row[StateIndex.Y], row[StateIndex.HEADING] = state.x, state.y, state.heading
            row[StateIndex.VELOCITY_X], row[StateIndex.ACCELERATION_X] = state.speed, state.accel
            row[StateIndex.STEERING_ANGLE], row[StateIndex.STEERING_RATE] = state.steering, state.steering_rate
            row[StateIndex.ANGULAR_VELOCITY], row[StateIndex.ANGULAR_ACCELERATION] = state.yaw_rate, state.yaw_accel


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
    reference, terms = tracking_reference(targets, PROPOSAL_INTERVAL, vehicle.wheel_base)
    first = initial_state(np.asarray(ego_velocity), np.asarray(ego_acceleration), tire_steering_angle)
    states = np.zeros((len(targets), targets.shape[1], STATE_SIZE))
    states[:, 0] = first
    # the bicycle's start: the t0 state at the origin of the ego frame, steering rate, yaw rate and yaw accel 0
    speed, accel, steering = first[[StateIndex.VELOCITY_X, StateIndex.ACCELERATION_X, StateIndex.STEERING_ANGLE]]
    start = BicycleState(0.0, 0.0, 0.0, float(speed), float(accel), float(steering), 0.0, 0.0, 0.0)
    _simulate(reference, terms, start, bicycle_constants(SIMULATION_DT, vehicle.wheel_base), states)
    return states
