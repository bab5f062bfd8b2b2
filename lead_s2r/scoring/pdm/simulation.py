"""NAVSIM's ``PDMSimulator.simulate_proposals``: 40 steps of LQR tracking + kinematic bicycle, batched over proposals.

The simulation starts from the logged ego state at t0 (rear axle, ego frame, so x = y = heading = 0): speed and
acceleration as logged (vy and ay included, in the body frame), the tire steering angle as given (NAVSIM: 0),
steering rate, yaw rate and yaw acceleration 0. Each step the tracker (``lqr.py``) turns the 41 targets from
``interpolation.py`` into commands and the bicycle (``bicycle.py``) applies them. Targets carry only poses: NAVSIM
gives the agent's states zero velocity and acceleration and the tracker never reads them.

The result equals the official one within the 1e-6 rounding of the golden files (``tests/test_pdm_simulation.py``,
every trajectory of the v1.1 and v2.2 files), in the ego frame instead of the global frame: every step is
invariant to a rigid motion of the scene. The 40 steps are sequential; each is ~80 tiny operations per proposal,
so up to ``SCALAR_PROPOSALS`` proposals run one by one on Python floats and more run together on numpy arrays,
through the same step code (``elementwise.py``). Costs: ``benchmarks/pdm_simulation.py``.
"""

import numpy as np

from lead_s2r.scoring.pdm.bicycle import BicycleConstants, BicycleState, bicycle_constants, heading_rate, propagate
from lead_s2r.scoring.pdm.elementwise import FLOATS, NUMPY, Elementwise
from lead_s2r.scoring.pdm.interpolation import PROPOSAL_INTERVAL
from lead_s2r.scoring.pdm.lqr import StepReference, step_references, stop_where_slow, track, tracking_reference
from lead_s2r.scoring.pdm.state import STATE_SIZE, StateIndex
from lead_s2r.scoring.pdm.vehicle import PACIFICA, VehicleParameters

#: nuPlan steps the bicycle by ``TimeDuration.from_s(0.1).time_s`` = 100000 us * 1e-6 (0.09999999999999999).
SIMULATION_DT = int(PROPOSAL_INTERVAL * 1e6) * 1e-6

#: Up to this many proposals, stepping each on Python floats beats numpy on tiny arrays (``elementwise.py``).
SCALAR_PROPOSALS = 6

#: The state columns the bicycle integrates, in ``BicycleState`` order (vy and ay are 0 after t0).
_BICYCLE_COLUMNS = [
    StateIndex.X,
    StateIndex.Y,
    StateIndex.HEADING,
    StateIndex.VELOCITY_X,
    StateIndex.ACCELERATION_X,
    StateIndex.STEERING_ANGLE,
    StateIndex.STEERING_RATE,
    StateIndex.ANGULAR_VELOCITY,
    StateIndex.ANGULAR_ACCELERATION,
]


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


def _run(
    references: list[StepReference],
    may_stop: list[bool],
    state: BicycleState,
    constants: BicycleConstants,
    wheel_base: float,
    ops: Elementwise,
) -> list[BicycleState]:
    """The states at every step, the given one first."""
    turn_rate = heading_rate(state, wheel_base, ops)
    history = [state]
    for reference, slow in zip(references, may_stop, strict=True):
        accel, steering_rate = track(reference, state.x, state.y, state.heading, state.speed, state.steering, ops)
        if slow:
            accel, steering_rate = stop_where_slow(reference, state.speed, accel, steering_rate, ops)
        state = propagate(state, turn_rate, accel, steering_rate, constants, ops)
        turn_rate = state.yaw_rate
        history.append(state)
    return history


def simulate_proposals(
    targets: np.ndarray,
    ego_velocity: np.ndarray,
    ego_acceleration: np.ndarray,
    tire_steering_angle: float = 0.0,
    vehicle: VehicleParameters = PACIFICA,
    scalar_proposals: int = SCALAR_PROPOSALS,
) -> np.ndarray:
    """Targets ``(N, T, 3)`` (T = 41: t = 0..4 s every 0.1 s, ego frame) -> simulated states ``(N, T, 11)``.

    Up to ``scalar_proposals`` proposals are stepped one by one on Python floats, more together on arrays; both
    give the same states to float rounding.
    """
    targets = np.asarray(targets, np.float64)
    if targets.ndim != 3 or targets.shape[-1] != 3 or targets.shape[1] < 4:
        raise ValueError(f"targets: expected shape (N, T >= 4, 3) of x, y, heading every 0.1 s, got {targets.shape}")
    count, num_states, _ = targets.shape
    wheel_base = vehicle.wheel_base
    fields, may_stop = tracking_reference(targets, PROPOSAL_INTERVAL, wheel_base)
    first = initial_state(np.asarray(ego_velocity), np.asarray(ego_acceleration), tire_steering_angle)
    states = np.zeros((count, num_states, STATE_SIZE))
    if count <= scalar_proposals:
        constants = bicycle_constants(SIMULATION_DT, wheel_base)
        start = BicycleState(*first[_BICYCLE_COLUMNS].tolist())
        for proposal in range(count):
            history = _run(step_references(fields, proposal), may_stop, start, constants, wheel_base, FLOATS)
            states[proposal][:, _BICYCLE_COLUMNS] = history
    else:
        constants = bicycle_constants(SIMULATION_DT, wheel_base, count)
        start = BicycleState(*(np.full(count, first[column]) for column in _BICYCLE_COLUMNS))
        history = _run(step_references(fields), may_stop, start, constants, wheel_base, NUMPY)
        for step, state in enumerate(history):  # column by column: cheaper than stacking the history first
            for column, values in zip(_BICYCLE_COLUMNS, state, strict=True):
                states[:, step, column] = values
    states[:, 0] = first
    return states
