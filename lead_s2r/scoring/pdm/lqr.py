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


@lru_cache(maxsize=8)
def _lookahead_weights(horizon: int, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Weights of the unrolled lateral dynamics over a lookahead of speeds u_k / dt = v + k dt a (k < horizon).

    Returns ``(horizon, 3)`` curvature weights (of sum u_k kappa_k split into v and a parts, and of
    sum_{j<k} kappa_j u_j u_k split into v^2, v a, a^2 parts, see ``_curvature_moments``) and the constants
    ``[sum_{j<k} u_j u_k, sum_{j<k} j u_j u_k]`` per v^2, v a, a^2, as a ``(2, 3)`` array.
    """
    k = np.arange(horizon, dtype=np.float64)
    first, second = np.triu_indices(horizon, 1)  # all pairs j < k
    # u_j u_k = dt^2 (v^2 + dt (j + k) v a + dt^2 j k a^2)
    pair_terms = dt**2 * np.stack([np.ones(len(first)), dt * (first + second), dt**2 * first * second], 1)
    curvature = np.zeros((horizon, 5))
    curvature[:, 0] = dt
    curvature[:, 1] = dt**2 * k
    np.add.at(curvature[:, 2:], first, pair_terms)
    constants = np.stack([pair_terms.sum(0), (first[:, None] * pair_terms).sum(0)])
    return curvature, constants


@dataclass
class TrackingReference:
    """What the tracker reads at each of the S = T - 1 steps, one row ``(N,)`` per step.

    ``moments`` (5, S, N): over the curvature lookahead, dt sum kappa_k, dt^2 sum k kappa_k and the three parts
    of sum_{j<k} kappa_j u_j u_k (per v^2, v a, a^2).
    """

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    sin: np.ndarray
    cos: np.ndarray
    speed: np.ndarray
    may_stop: list[bool]
    moments: np.ndarray


def tracking_reference(targets: np.ndarray, dt: float) -> TrackingReference:
    """Targets ``(N, T, 3)`` -> the tracker's references at each of the T - 1 tracking steps."""
    steps = np.diff(targets, axis=1)
    headings = targets[:, :-1, 2]
    projected = np.cos(headings) * steps[..., 0] + np.sin(headings) * steps[..., 1]
    num_fits = steps.shape[1]
    speed = projected @ _speed_fit_matrix(num_fits, dt).T
    curvature = _curvature_profile(wrap_angle(steps[..., 2]), speed, dt)
    ahead = np.minimum(np.arange(num_fits)[:, None] + np.arange(TRACKING_HORIZON + 1), num_fits - 1)  # (S, H + 1)
    reference_speed = speed[:, ahead[:, -1]].T
    weights, _ = _lookahead_weights(TRACKING_HORIZON, dt)
    moments = np.moveaxis(curvature[:, ahead[:, :-1]] @ weights, -1, 0).transpose(0, 2, 1)
    poses = np.ascontiguousarray(targets[:, :-1].transpose(2, 1, 0))
    return TrackingReference(
        x=poses[0],
        y=poses[1],
        heading=poses[2],
        sin=np.sin(poses[2]),
        cos=np.cos(poses[2]),
        speed=reference_speed,
        may_stop=list((reference_speed <= STOPPING_VELOCITY).any(axis=1)),
        moments=np.ascontiguousarray(moments),
    )


def track(
    ref: TrackingReference,
    step: int,
    ego: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    dt: float,
    wheel_base: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration and steering-rate commands ``(N,)`` for ego ``(x, y, heading, speed, steering)`` at ``step``.

    Lateral problem unrolled over the lookahead (u_k = v_k dt, steering s constant, U_k / W_k the sums of u_j and
    u_j kappa_j over j < k): heading error h_k = h + s U_k / L - W_k, lateral error e + sum_k u_k h_k; a unit
    steering rate adds k dt to the steering angle before step k. Every sum is a polynomial in the ego speed v and
    the acceleration command a, with the curvature parts precomputed in ``ref.moments``.
    """
    x, y, heading, speed, steering = ego
    lateral_error = (y - ref.y[step]) * ref.cos[step] - (x - ref.x[step]) * ref.sin[step]
    heading_error = wrap_angle(heading - ref.heading[step])
    reference_speed = ref.speed[step]

    horizon, horizon_time = TRACKING_HORIZON, TRACKING_HORIZON * dt
    gain = -1.0 / (horizon_time * Q_LONGITUDINAL * horizon_time + R_LONGITUDINAL) * horizon_time * Q_LONGITUDINAL
    accel = gain * (speed - reference_speed)

    _, (pairs, index_pairs) = _lookahead_weights(horizon, dt)
    k_sum, k_sq_sum = horizon * (horizon - 1) / 2, (horizon - 1) * horizon * (2 * horizon - 1) / 6
    v_sq, v_a, a_sq = speed * speed, speed * accel, accel * accel
    u_sum = dt * horizon * speed + dt**2 * k_sum * accel
    m = ref.moments[:, step]
    steer_per_length = steering / wheel_base
    final_heading = wrap_angle(heading_error + steer_per_length * u_sum - (m[0] * speed + m[1] * accel))
    uu = pairs[0] * v_sq + pairs[1] * v_a + pairs[2] * a_sq
    kuu = m[2] * v_sq + m[3] * v_a + m[4] * a_sq
    final_error = lateral_error + heading_error * u_sum + steer_per_length * uu - kuu
    input_heading = dt / wheel_base * (dt * k_sum * speed + dt**2 * k_sq_sum * accel)
    input_error = dt / wheel_base * (index_pairs[0] * v_sq + index_pairs[1] * v_a + index_pairs[2] * a_sq)
    q_error, q_heading, _ = Q_LATERAL  # the steering-angle weight is 0
    lateral_gain = -1.0 / (q_error * input_error * input_error + q_heading * input_heading * input_heading + R_LATERAL)
    steering_rate = lateral_gain * (q_error * input_error * final_error + q_heading * input_heading * final_heading)

    if ref.may_stop[step]:
        stopping = (reference_speed <= STOPPING_VELOCITY) & (speed <= STOPPING_VELOCITY)
        accel = np.where(stopping, -STOPPING_GAIN * (speed - reference_speed), accel)
        steering_rate = np.where(stopping, 0.0, steering_rate)
    return accel, steering_rate
