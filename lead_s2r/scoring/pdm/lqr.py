"""NAVSIM's batched LQR tracker (``pdm_planner/simulation/batch_lqr.py`` + ``batch_lqr_utils.py``), in closed form.

The tracker decouples a longitudinal problem (state: speed; input: acceleration) from a lateral one (states:
lateral error, heading error, steering angle; input: steering rate), each a one-step LQR over a 10-step
lookahead of 0.1 s. Constants: longitudinal Q = 10, R = 1; lateral Q = diag(1, 10, 0), R = 1; jerk penalty 1e-4
and curvature-rate penalty 1e-2 (initial-curvature penalty 1e-10) in the reference fits; when both the reference
speed (10 steps ahead) and the ego speed are <= 0.2 m/s a P controller takes over (gain 0.5, steering rate 0).

Reference speed and curvature come from regularised least squares on the 41 target poses, as nuPlan's tracker
does. NAVSIM forms the normal equations and applies ``np.linalg.pinv`` per proposal; here the same minimisers are
computed with less work, equal up to float rounding:

- speed: the normal matrix does not depend on the poses (cos^2 + sin^2 = 1), so the whole fit is one constant
  (40 x 40) matrix applied to the displacements projected on the target headings;
- curvature: the normal matrix ``w_c w_c' sum_{i >= max(c, c')} v_i^2 + Q`` is built from suffix sums and solved
  (``np.linalg.solve``; positive definite thanks to the 1e-10 initial-curvature penalty);
- lateral dynamics: the product of the 10 step matrices is unrolled into cumulative sums over the lookahead.

Reproduced on purpose: the reference index is clipped to the last fitted speed (39) and the curvature lookahead
is padded with the curvature there; the heading and steering entries of the zero-input lateral error are wrapped
with ``arctan2(sin, cos)``; the lookahead speeds of the lateral problem are the ego's own speed under the new
acceleration command, not the reference's. NAVSIM evaluates the tracker with ``discretization_time = 0.1`` while
the bicycle steps by nuPlan's ``TimeDuration(100000 us).time_s`` (0.09999999999999999); both are kept.
"""

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

Q_LONGITUDINAL = 10.0
R_LONGITUDINAL = 1.0
Q_LATERAL = (1.0, 10.0, 0.0)  # lateral error, heading error, steering angle
R_LATERAL = 1.0
TRACKING_HORIZON = 10
JERK_PENALTY = 1e-4
CURVATURE_RATE_PENALTY = 1e-2
INITIAL_CURVATURE_PENALTY = 1e-10
STOPPING_GAIN = 0.5
STOPPING_VELOCITY = 0.2


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """NAVSIM ``normalize_angle``: ``arctan2(sin, cos)``, in (-pi, pi]."""
    return np.arctan2(np.sin(angle), np.cos(angle))


@lru_cache(maxsize=8)
def _speed_fit_matrix(num_displacements: int, dt: float) -> np.ndarray:
    """``(M, M)``: projected displacements -> fitted speed at each pose (``v0`` then ``v0 + dt * cumsum(a)``).

    nuPlan's design matrix has entry ``heading_column * w_c`` for c <= i (w_0 = dt, w_c = dt^2), so its normal
    matrix is ``w_c w_c' (M - max(c, c'))`` and its right-hand side ``w_c`` times suffix sums of the projections.
    """
    m = num_displacements
    weights = np.full(m, dt**2)
    weights[0] = dt
    index = np.arange(m)
    normal = np.outer(weights, weights) * (m - np.maximum.outer(index, index))
    # nuPlan's ``_make_banded_difference_matrix`` writes +1 above the diagonal, then overwrites with -eye: every
    # row but the last penalises an acceleration itself, not a jerk (NAVSIM keeps this; so do we)
    jerk = np.zeros((m - 2, m))
    jerk[:, 1:-1] = -np.eye(m - 2)
    jerk[-1, -1] = 1.0
    suffix = np.triu(np.ones((m, m)))  # (c, i): 1 where i >= c
    solution = np.linalg.solve(normal + JERK_PENALTY * jerk.T @ jerk, weights[:, None] * suffix)
    integrate = np.tri(m) * dt  # speed_k = v0 + dt * sum_{j < k} a_j
    integrate[:, 0] = 1.0
    return integrate @ solution


def _curvature_profile(heading_steps: np.ndarray, speed: np.ndarray, dt: float) -> np.ndarray:
    """``(N, M)`` curvature at each pose from heading displacements and fitted speeds ``(N, M)``.

    Unknowns: initial curvature and M - 1 curvature rates; row i predicts ``speed_i * dt * curvature_i``.
    """
    m = speed.shape[1]
    weights = np.full(m, dt**2)
    weights[0] = dt
    index = np.arange(m)
    suffix_sq = np.cumsum((speed**2)[:, ::-1], axis=1)[:, ::-1]  # sum_{i >= c} v_i^2
    normal = suffix_sq[:, np.maximum.outer(index, index)] * np.outer(weights, weights)
    normal[:, index[1:], index[1:]] += CURVATURE_RATE_PENALTY
    normal[:, 0, 0] += INITIAL_CURVATURE_PENALTY
    rhs = np.cumsum((speed * heading_steps)[:, ::-1], axis=1)[:, ::-1] * weights
    solution = np.linalg.solve(normal, rhs[..., None])[..., 0]
    return solution[:, :1] + np.concatenate([np.zeros((len(speed), 1)), np.cumsum(solution[:, 1:] * dt, 1)], 1)


@dataclass
class ReferenceProfiles:
    """Per proposal and step: reference speed 10 steps ahead ``(N, S)``, curvature lookahead ``(N, S, 10)``."""

    speed: np.ndarray
    curvature: np.ndarray


def reference_profiles(targets: np.ndarray, dt: float) -> ReferenceProfiles:
    """Targets ``(N, T, 3)`` -> the tracker's references at each of the T - 1 tracking steps."""
    steps = np.diff(targets, axis=1)
    headings = targets[:, :-1, 2]
    projected = np.cos(headings) * steps[..., 0] + np.sin(headings) * steps[..., 1]
    num_fits = steps.shape[1]
    speed = projected @ _speed_fit_matrix(num_fits, dt).T
    curvature = _curvature_profile(wrap_angle(steps[..., 2]), speed, dt)
    step_index = np.arange(num_fits)
    ahead = np.minimum(step_index[:, None] + np.arange(TRACKING_HORIZON + 1), num_fits - 1)  # (S, 11)
    return ReferenceProfiles(speed=speed[:, ahead[:, -1]], curvature=curvature[:, ahead[:, :-1]])


def _lateral_steering_rate(
    lateral_state: np.ndarray, speeds: np.ndarray, curvature: np.ndarray, dt: float, wheel_base: float
) -> np.ndarray:
    """One-step lateral LQR: steering rate ``(N,)`` from the error state ``(N, 3)`` and lookahead ``(N, H)``.

    Step k maps (e, h, s) to (e + u_k h, h + u_k s / L - u_k kappa_k, s) with u_k = v_k dt; the input enters the
    steering angle with dt. Unrolled: h_k = h_0 + s_0 U_k / L - W_k with U, W exclusive cumulative sums.
    """
    error, heading, steering = lateral_state[:, 0], lateral_state[:, 1], lateral_state[:, 2]
    u = speeds * dt
    u_sum = np.cumsum(u, axis=1)
    w_sum = np.cumsum(u * curvature, axis=1)
    before_u = u_sum - u  # sum_{j < k}
    before_w = w_sum - u * curvature
    heading_k = heading[:, None] + steering[:, None] * before_u / wheel_base - before_w
    final_error = error + np.sum(u * heading_k, axis=1)
    final_heading = wrap_angle(heading + steering * u_sum[:, -1] / wheel_base - w_sum[:, -1])
    # response to a unit input: steering angle k dt before step k; heading, then lateral error, accumulate it
    input_steering = np.arange(speeds.shape[1]) * dt
    input_heading_after = np.cumsum(u * input_steering / wheel_base, axis=1)
    input_error = np.sum(u * (input_heading_after - u * input_steering / wheel_base), axis=1)
    input_heading = input_heading_after[:, -1]
    q_error, q_heading, _ = Q_LATERAL  # the steering-angle weight is 0
    gain = -1.0 / (q_error * input_error**2 + q_heading * input_heading**2 + R_LATERAL)
    return gain * (q_error * input_error * final_error + q_heading * input_heading * final_heading)


def track(
    states: np.ndarray, targets: np.ndarray, profiles: ReferenceProfiles, step: int, dt: float, wheel_base: float
) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration and steering-rate commands ``(N,)`` for ego states ``(N, 11)`` at tracking step ``step``."""
    target = targets[:, step]
    dx, dy = states[:, 0] - target[:, 0], states[:, 1] - target[:, 1]
    lateral_error = -dx * np.sin(target[:, 2]) + dy * np.cos(target[:, 2])
    heading_error = wrap_angle(states[:, 2] - target[:, 2])
    speed, reference_speed = states[:, 3], profiles.speed[:, step]

    horizon_time = TRACKING_HORIZON * dt
    accel = -1.0 / (horizon_time * Q_LONGITUDINAL * horizon_time + R_LONGITUDINAL)
    accel = accel * horizon_time * Q_LONGITUDINAL * (speed - reference_speed)
    lookahead = speed[:, None] + np.arange(TRACKING_HORIZON) * (accel * dt)[:, None]
    lateral_state = np.stack([lateral_error, heading_error, states[:, 7]], axis=1)
    steering_rate = _lateral_steering_rate(lateral_state, lookahead, profiles.curvature[:, step], dt, wheel_base)

    stopping = (reference_speed <= STOPPING_VELOCITY) & (speed <= STOPPING_VELOCITY)
    accel = np.where(stopping, -STOPPING_GAIN * (speed - reference_speed), accel)
    steering_rate = np.where(stopping, 0.0, steering_rate)
    return accel, steering_rate
