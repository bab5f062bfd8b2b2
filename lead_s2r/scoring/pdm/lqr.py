"""NAVSIM's batched LQR tracker (``pdm_planner/simulation/batch_lqr.py`` + ``batch_lqr_utils.py``), in closed form.

The tracker decouples a longitudinal problem (state: speed; input: acceleration) from a lateral one (states:
lateral error, heading error, steering angle; input: steering rate), each a one-step LQR over a 10-step
lookahead of 0.1 s. Constants: longitudinal Q = 10, R = 1; lateral Q = diag(1, 10, 0), R = 1; "jerk" penalty
1e-4 and curvature-rate penalty 1e-2 (initial-curvature penalty 1e-10) in the reference fits; when both the
reference speed (10 steps ahead) and the ego speed are <= 0.2 m/s a P controller takes over (gain 0.5, steering
rate 0).

Reference speed and curvature come from regularised least squares on the 41 target poses, as nuPlan's tracker
does. NAVSIM forms the normal equations and applies ``np.linalg.pinv`` per proposal; here the same minimisers are
computed with less work, equal up to float rounding (``tests/test_pdm_simulation.py``):

- speed: the normal matrix does not depend on the poses (cos^2 + sin^2 = 1), so the whole fit is one constant
  (40 x 40) matrix applied to the displacements projected on the target headings;
- curvature: the normal matrix ``w_c w_c' sum_{i >= max(c, c')} v_i^2 + Q`` becomes tridiagonal after a change
  of variables and is solved in O(M) per proposal (``curvature_profile``; positive definite thanks to the 1e-10
  initial-curvature penalty);
- lateral dynamics: the product of the 10 step matrices is unrolled into sums over the lookahead that are
  polynomials in the ego speed, their coefficients precomputed for every step (``tracking_reference``); each
  step then costs ~50 arithmetic operations per proposal.

Reproduced on purpose (official behaviours, not ours to fix):

- the "jerk" penalty is mostly an acceleration penalty: nuPlan's ``_make_banded_difference_matrix`` writes the
  +1 band, then *overwrites* the diagonal band with ``-eye``, erasing every +1 but the last row's; ignoring this
  moves the simulated speed by up to ~0.05 m/s (found against the golden files);
- the reference index is clipped to the last fitted speed (39) and the curvature lookahead padded with the
  curvature there; the heading (and steering) entries of the zero-input lateral error are wrapped with
  ``arctan2(sin, cos)``; the lookahead speeds of the lateral problem are the ego's own speed under the new
  acceleration command, not the reference's;
- the tracker uses ``discretization_time = 0.1`` while the bicycle steps by nuPlan's ``TimeDuration(100000
  us).time_s`` (0.09999999999999999); both are kept.
"""

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from lead_s2r.scoring.pdm.elementwise import NUMPY, Elementwise, Values, row_products

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
#: up to this many rows the curvature fit runs on Python floats (cheaper than ~300 numpy calls on tiny arrays)
SCALAR_ROWS = 8


def normalize_angle(angle: Values, ops: Elementwise = NUMPY) -> Values:
    """NAVSIM ``normalize_angle``: ``arctan2(sin, cos)``, in (-pi, pi]."""
    return ops.arctan2(ops.sin(angle), ops.cos(angle))


@lru_cache(maxsize=8)
def speed_fit_matrix(num_displacements: int, dt: float) -> np.ndarray:
    """``(M, M)``: projected displacements -> fitted speed at each pose (``v0`` then ``v0 + dt * cumsum(a)``).

    nuPlan's design matrix has entry ``heading_column * w_c`` for c <= i (w_0 = dt, w_c = dt^2), so its normal
    matrix is ``w_c w_c' (M - max(c, c'))`` and its right-hand side ``w_c`` times suffix sums of the projections.
    """
    m = num_displacements
    weights = np.full(m, dt**2)
    weights[0] = dt
    index = np.arange(m)
    normal = np.outer(weights, weights) * (m - np.maximum.outer(index, index))
    # nuPlan's banded "difference" matrix after its overwrite (module docstring): -a_{r} on every row, plus
    # a_{M-2} on the last one
    jerk = np.zeros((m - 2, m))
    jerk[:, 1:-1] = -np.eye(m - 2)
    jerk[-1, -1] = 1.0
    suffix = np.triu(np.ones((m, m)))  # (c, i): 1 where i >= c
    solution = np.linalg.solve(normal + JERK_PENALTY * jerk.T @ jerk, weights[:, None] * suffix)
    integrate = np.tri(m) * dt  # speed_k = v0 + dt * sum_{j < k} a_j
    integrate[:, 0] = 1.0
    return integrate @ solution


def curvature_profile(heading_steps: np.ndarray, speed: np.ndarray, dt: float) -> np.ndarray:
    """``(N, M)`` curvature at each pose from heading displacements and fitted speeds ``(N, M)``.

    Unknowns: initial curvature x_0 and M - 1 curvature rates x_c; row i predicts ``speed_i * dt * curvature_i``.
    The normal matrix ``w_c w_c' S_max(c, c') + P_c`` (S: suffix sums of v^2) is, in y_c = w_c x_c, U diag(v^2) U^T
    plus a diagonal (U: the upper triangle of ones). With z = U^T y (prefix sums of y) the system is tridiagonal,
    ``(v_i^2 + d_i + d_i+1) z_i - d_i z_i-1 - d_i+1 z_i+1 = v_i h_i`` with d_c = P_c / w_c^2, and the curvature at
    pose k, x_0 + dt (x_1 + ... + x_k), telescopes to z_k / dt. Thomas' recursion solves it without pivoting (the
    matrix is diagonally dominant) in O(M) per row instead of a dense solve; a few rows run on Python floats, more
    on columns of all rows, the same operations in the same order, so a row's bits do not depend on its neighbours.
    """
    count, m = speed.shape
    weights = np.full(m, dt**2)
    weights[0] = dt
    penalties = np.full(m, CURVATURE_RATE_PENALTY)
    penalties[0] = INITIAL_CURVATURE_PENALTY
    coupling = np.append(penalties / weights**2, 0.0).tolist()  # d_0 .. d_M-1, and 0 past the last pose
    diagonal = (speed * speed).T + np.add(coupling[:-1], coupling[1:])[:, None]  # (M, N)
    rhs = (speed * heading_steps).T
    if count <= SCALAR_ROWS:
        rows = [_tridiagonal(diagonal[:, n].tolist(), rhs[:, n].tolist(), coupling) for n in range(count)]
        return np.array(rows, dtype=np.float64).reshape(count, m) / dt
    return np.stack(_tridiagonal(list(diagonal), list(rhs), coupling), axis=1) / dt


def _tridiagonal(diagonal: list[Values], rhs: list[Values], coupling: list[float]) -> list[Values]:
    """z solving ``diagonal_i z_i - coupling_i z_i-1 - coupling_i+1 z_i+1 = rhs_i`` (Thomas' recursion)."""
    ratios, scaled = [], []
    for i, (pivot_base, right) in enumerate(zip(diagonal, rhs, strict=True)):
        if i:
            pivot = pivot_base - coupling[i] * ratios[-1]
            scaled.append((right + coupling[i] * scaled[-1]) / pivot)
        else:
            pivot = pivot_base
            scaled.append(right / pivot)
        ratios.append(coupling[i + 1] / pivot)
    solution = [scaled[-1]]
    for ratio, value in zip(ratios[-2::-1], scaled[-2::-1], strict=True):
        solution.append(value + ratio * solution[-1])
    return solution[::-1]


@lru_cache(maxsize=8)
def _lookahead_terms(horizon: int, dt: float, wheel_base: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The unrolled lateral dynamics as polynomials in the ego speed v and acceleration command a.

    Over the lookahead the speed is v + k dt a, so u_k = v_k dt = dt v + dt^2 k a and every sum below is linear
    (coefficients of v, a) or quadratic (coefficients of v^2, v a, a^2) in them. Returns the ``(horizon, 5)``
    weights that turn a curvature lookahead into the curvature-dependent coefficients (sum u_k kappa_k: 2;
    sum_{j<k} kappa_j u_j u_k: 3) and the fixed coefficients of the other sums.
    """
    k = np.arange(horizon, dtype=np.float64)
    first, second = np.triu_indices(horizon, 1)  # all pairs j < k
    # u_j u_k = dt^2 (v^2 + dt (j + k) v a + dt^2 j k a^2)
    pair_terms = dt**2 * np.stack([np.ones(len(first)), dt * (first + second), dt**2 * first * second], 1)
    curvature = np.zeros((horizon, 5))
    curvature[:, 0] = dt
    curvature[:, 1] = dt**2 * k
    np.add.at(curvature[:, 2:], first, pair_terms)
    fixed = {
        "u_sum": np.array([dt * horizon, dt**2 * k.sum()]),  # sum_k u_k
        "pairs": pair_terms.sum(0),  # sum_{j<k} u_j u_k
        # response to a unit steering rate: steering k dt before step k, heading sum_k u_k k dt / L, lateral error
        "input_heading": dt / wheel_base * np.array([dt * k.sum(), dt**2 * (k * k).sum()]),
        "input_error": dt / wheel_base * (first[:, None] * pair_terms).sum(0),
    }
    return curvature, fixed


class StepReference(NamedTuple):
    """What the tracker needs at one step, each ``(N,)`` (or a float per proposal): the target pose and the lateral
    problem's polynomials in the ego speed v (the acceleration command being ``accel_per_speed * v +
    accel_offset``), highest power first. Constants are rows too: numpy multiplies two arrays faster than a Python
    float and an array."""

    x: Values
    y: Values
    sin: Values
    cos: Values
    heading: Values
    speed: Values
    accel_per_speed: Values
    accel_offset: Values
    u_sum_1: Values  # sum_k u_k
    u_sum_0: Values
    curvature_1: Values  # sum_k u_k kappa_k
    curvature_0: Values
    pairs_2: Values  # sum_{j<k} u_j u_k
    pairs_1: Values
    pairs_0: Values
    curvature_pairs_2: Values  # sum_{j<k} kappa_j u_j u_k
    curvature_pairs_1: Values
    curvature_pairs_0: Values
    input_heading_1: Values
    input_heading_0: Values
    input_error_2: Values
    input_error_1: Values
    input_error_0: Values
    inverse_wheel_base: Values
    q_heading: Values
    r_lateral: Values


def _linear_in_speed(coefficients: np.ndarray, accel: tuple[float, np.ndarray]) -> list[np.ndarray]:
    """``c_v v + c_a a`` with ``a = a_1 v + a_0`` as ``[coefficient of v, constant]``."""
    c_v, c_a = coefficients
    return [c_v + c_a * accel[0], c_a * accel[1]]


def _quadratic_in_speed(coefficients: np.ndarray, accel: tuple[float, np.ndarray]) -> list[np.ndarray]:
    """``c_vv v^2 + c_va v a + c_aa a^2`` with ``a = a_1 v + a_0`` as ``[coefficient of v^2, of v, constant]``."""
    c_vv, c_va, c_aa = coefficients
    a_1, a_0 = accel
    return [c_vv + c_va * a_1 + c_aa * a_1 * a_1, c_va * a_0 + 2 * c_aa * a_1 * a_0, c_aa * a_0 * a_0]


def tracking_reference(
    targets: np.ndarray, dt: float, wheel_base: float
) -> tuple[list[np.ndarray | float], list[bool]]:
    """Targets ``(N, T, 3)`` -> the ``StepReference`` fields, each ``(T - 1, N)`` laid out step-major (a step's row
    of proposals contiguous) or one float for every step and proposal; and whether any reference speed is slow
    enough for the stopping controller at each step."""
    steps = np.diff(targets, axis=1)
    headings = targets[:, :-1, 2]
    sin, cos = np.sin(headings), np.cos(headings)  # the fit's projection and the tracker's target frames alike
    projected = cos * steps[..., 0] + sin * steps[..., 1]
    num_fits = steps.shape[1]
    speed = row_products(projected, speed_fit_matrix(num_fits, dt).T)
    curvature = curvature_profile(normalize_angle(steps[..., 2]), speed, dt)
    ahead = np.minimum(np.arange(num_fits)[:, None] + np.arange(TRACKING_HORIZON + 1), num_fits - 1)  # (S, H + 1)
    # laid out step-major once here, so that the fields computed from them are too (np.take: far faster than fancy
    # indexing)
    reference_speed = np.ascontiguousarray(np.take(speed, ahead[:, -1], axis=1).T)  # (S, N)
    weights, fixed = _lookahead_terms(TRACKING_HORIZON, dt, wheel_base)
    # one (S, H) @ (H, 5) product per proposal (a stack of them: a proposal's bits do not depend on the others)
    lookahead = curvature[:, ahead[:, :-1]]
    moments = np.ascontiguousarray(np.moveaxis(lookahead @ weights, -1, 0).transpose(0, 2, 1))  # (5, S, N)

    horizon_time = TRACKING_HORIZON * dt
    gain = -1.0 / (horizon_time * Q_LONGITUDINAL * horizon_time + R_LONGITUDINAL) * horizon_time * Q_LONGITUDINAL
    accel = (gain, -gain * reference_speed)  # the longitudinal LQR: a = gain (v - v_ref)
    poses = np.ascontiguousarray(targets[:, :-1].transpose(2, 1, 0))
    fields = [
        poses[0],
        poses[1],
        np.ascontiguousarray(sin.T),
        np.ascontiguousarray(cos.T),
        poses[2],
        reference_speed,
        gain,
        accel[1],
        *_linear_in_speed(fixed["u_sum"], accel),
        *_linear_in_speed(moments[:2], accel),
        *_quadratic_in_speed(fixed["pairs"], accel),
        *_quadratic_in_speed(moments[2:], accel),
        *_linear_in_speed(fixed["input_heading"], accel),
        *_quadratic_in_speed(fixed["input_error"], accel),
        1.0 / wheel_base,
        Q_LATERAL[1],
        R_LATERAL,
    ]
    may_stop = (reference_speed <= STOPPING_VELOCITY).any(axis=1).tolist()
    return fields, may_stop


def step_references(fields: list[np.ndarray | float], proposal: int | None = None) -> list[StepReference]:
    """Per step, the rows of all proposals (each field's ``(N,)`` row; a constant one array shared by every step),
    or the Python floats of one ``proposal``."""
    num_steps, count = next(field.shape for field in fields if isinstance(field, np.ndarray))
    rows = [
        field if isinstance(field, np.ndarray) else np.broadcast_to(np.full(count, field), (num_steps, count))
        for field in fields
    ]
    if proposal is None:
        return [StepReference(*(row[step] for row in rows)) for step in range(num_steps)]
    return [StepReference(*step) for step in zip(*(row[:, proposal].tolist() for row in rows), strict=True)]


def track(
    ref: StepReference, x: Values, y: Values, heading: Values, speed: Values, steering: Values, ops: Elementwise
) -> tuple[Values, Values]:
    """Acceleration and steering-rate commands for the ego pose, speed and steering angle (arrays or floats).

    Lateral problem unrolled over the lookahead (u_k = v_k dt, steering s constant, U_k / W_k the sums of u_j and
    u_j kappa_j over j < k): heading error h_k = h + s U_k / L - W_k, lateral error e + sum_k u_k h_k
    = e + h U + s / L sum_{j<k} u_j u_k - sum_{j<k} kappa_j u_j u_k; a unit steering rate adds k dt to the
    steering angle before step k. Q_LATERAL's lateral-error weight is 1 and its steering weight 0, so neither
    appears below.
    """
    lateral_error = (y - ref.y) * ref.cos - (x - ref.x) * ref.sin
    heading_error = normalize_angle(heading - ref.heading, ops)
    accel = ref.accel_per_speed * speed + ref.accel_offset

    u_sum = ref.u_sum_1 * speed + ref.u_sum_0
    steer_per_length = steering * ref.inverse_wheel_base
    final_heading = normalize_angle(
        heading_error + steer_per_length * u_sum - (ref.curvature_1 * speed + ref.curvature_0), ops
    )
    pairs = (ref.pairs_2 * speed + ref.pairs_1) * speed + ref.pairs_0
    curvature_pairs = (ref.curvature_pairs_2 * speed + ref.curvature_pairs_1) * speed + ref.curvature_pairs_0
    final_error = lateral_error + heading_error * u_sum + steer_per_length * pairs - curvature_pairs
    input_heading = ref.input_heading_1 * speed + ref.input_heading_0
    input_error = (ref.input_error_2 * speed + ref.input_error_1) * speed + ref.input_error_0
    weighted_heading = ref.q_heading * input_heading
    denominator = input_error * input_error + weighted_heading * input_heading + ref.r_lateral
    steering_rate = (input_error * final_error + weighted_heading * final_heading) / denominator
    return accel, -steering_rate


def stop_where_slow(
    ref: StepReference, speed: Values, accel: Values, steering_rate: Values, ops: Elementwise
) -> tuple[Values, Values]:
    """The stopping P controller replaces the LQR where reference and ego speed are both <= 0.2 m/s."""
    stopping = (ref.speed <= STOPPING_VELOCITY) & (speed <= STOPPING_VELOCITY)
    accel = ops.where(stopping, -STOPPING_GAIN * (speed - ref.speed), accel)
    return accel, ops.where(stopping, 0.0, steering_rate)
