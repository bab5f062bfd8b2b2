"""NAVSIM's batched LQR tracker (``pdm_planner/simulation/batch_lqr.py`` + ``batch_lqr_utils.py``), in closed form.

The tracker decouples a longitudinal problem (state: speed; input: acceleration) from a lateral one (states: lateral
error, heading error, steering angle; input: steering rate), each a one-step LQR over a 10-step lookahead of 0.1 s.
Constants: longitudinal Q = 10, R = 1; lateral Q = diag(1, 10, 0), R = 1; "jerk" penalty 1e-4 and curvature-rate penalty
1e-2 (initial-curvature penalty 1e-10) in the reference fits; when both the reference speed (10 steps ahead) and the ego
speed are <= 0.2 m/s a P controller takes over (gain 0.5, steering rate 0).

Reference speed and curvature come from regularised least squares on the 41 target poses, as nuPlan's tracker
does. NAVSIM forms the normal equations and applies ``np.linalg.pinv`` per proposal; here the same minimisers are
computed with less work, equal up to float rounding (``tests/test_pdm_simulation.py``):

- speed: the normal matrix does not depend on the poses (cos^2 + sin^2 = 1), so the whole fit is one constant
  (40 x 40) matrix applied to the displacements projected on the target headings;
- curvature: the normal matrix ``w_c w_c' sum_{i >= max(c, c')} v_i^2 + Q`` becomes tridiagonal after a change
  of variables and is solved in O(M) per proposal (``curvature_profile``; positive definite thanks to the 1e-10
  initial-curvature penalty);
- lateral dynamics: the product of the 10 step matrices is unrolled into sums over the lookahead that are
  polynomials in the ego speed and acceleration command, their curvature moments precomputed for every step
  (``tracking_reference``); each step then costs ~50 arithmetic operations per proposal (``track``, compiled).

Reproduced on purpose (official behaviours, not ours to fix):

- the "jerk" penalty is mostly an acceleration penalty: nuPlan's ``_make_banded_difference_matrix`` writes the
  +1 band, then *overwrites* the diagonal band with ``-eye``, erasing every +1 but the last row's; ignoring this
  moves the simulated speed by up to ~0.05 m/s (found against the golden files);
- the reference index is clipped to the last fitted speed (39) and the curvature lookahead padded with the
  curvature there; the heading (and steering) entries of the zero-input lateral error are wrapped to
  [-pi, pi] (NAVSIM: ``arctan2(sin, cos)``; here by whole turns, ``normalize_angle``); the lookahead speeds of
  the lateral problem are the ego's own speed under the new acceleration command, not the reference's;
- the tracker uses ``discretization_time = 0.1`` while the bicycle steps by nuPlan's ``TimeDuration(100000
  us).time_s`` (0.09999999999999999); both are kept.
"""

from functools import lru_cache
from typing import NamedTuple

import numpy as np
from numba import njit

from lead_s2r.scoring.pdm.rowwise import Values, row_products

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
TWO_PI = 2 * np.pi


@njit(cache=True)
def normalize_angle(angle: Values) -> Values:
    """NAVSIM's ``normalize_angle``, ``arctan2(sin, cos)``, as a wrap by whole turns: an angle in [-pi, pi] is kept
    (``arctan2`` gives it back up to its rounding), one beyond loses one turn, which lands on ``arctan2``'s branch
    at +-pi too (ties round to the even turn, 0). Three transcendentals per angle were a third of the simulation.
    """
    return angle - TWO_PI * np.rint(angle / TWO_PI)


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
    matrix is diagonally dominant) in O(M) per row instead of a dense solve.
    """
    m = speed.shape[1]
    weights = np.full(m, dt**2)
    weights[0] = dt
    penalties = np.full(m, CURVATURE_RATE_PENALTY)
    penalties[0] = INITIAL_CURVATURE_PENALTY
    coupling = np.append(penalties / weights**2, 0.0)  # d_0 .. d_M-1, and 0 past the last pose
    diagonal = speed * speed + (coupling[:-1] + coupling[1:])
    return _tridiagonal(diagonal, speed * heading_steps, coupling) / dt


@njit(cache=True)
def _tridiagonal(diagonal: np.ndarray, rhs: np.ndarray, coupling: np.ndarray) -> np.ndarray:
    """Per row of ``(N, M)``, z solving ``diagonal_i z_i - coupling_i z_i-1 - coupling_i+1 z_i+1 = rhs_i``
    (Thomas' recursion, row by row)."""
    count, m = diagonal.shape
    solution = np.empty((count, m))
    ratios = np.empty(m)
    for n in range(count):
        pivot = diagonal[n, 0]
        solution[n, 0] = rhs[n, 0] / pivot
        ratios[0] = coupling[1] / pivot
        for i in range(1, m):
            pivot = diagonal[n, i] - coupling[i] * ratios[i - 1]
            solution[n, i] = (rhs[n, i] + coupling[i] * solution[n, i - 1]) / pivot
            ratios[i] = coupling[i + 1] / pivot
        for i in range(m - 2, -1, -1):
            solution[n, i] += ratios[i] * solution[n, i + 1]
    return solution


@njit(cache=True)
def _lookahead_moments(curvature: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``(N, M, 5)``: at each pose, the curvatures of the lookahead (clipped to the last pose) times ``weights (H,
    5)``, summed in lookahead order."""
    count, m = curvature.shape
    moments = np.zeros((count, m, weights.shape[1]))
    for n in range(count):
        for s in range(m):
            for h in range(weights.shape[0]):
                kappa = curvature[n, min(s + h, m - 1)]
                for moment in range(weights.shape[1]):
                    moments[n, s, moment] += kappa * weights[h, moment]
    return moments


class LateralTerms(NamedTuple):
    """The scene-independent coefficients of the unrolled lateral problem (``_lookahead_terms``) and the gains, as
    floats the compiled tracker reads: linear forms ``c_v v + c_a a``, quadratic ones ``c_vv v^2 + c_va v a +
    c_aa a^2`` in the ego speed v and the acceleration command a."""

    accel_gain: float  # the longitudinal LQR: a = gain (v - v_ref)
    u_sum_v: float  # sum_k u_k
    u_sum_a: float
    pairs_vv: float  # sum_{j<k} u_j u_k
    pairs_va: float
    pairs_aa: float
    input_heading_v: float  # heading response to a unit steering rate
    input_heading_a: float
    input_error_vv: float  # lateral-error response to a unit steering rate
    input_error_va: float
    input_error_aa: float
    inverse_wheel_base: float


class TrackingReference(NamedTuple):
    """What the tracker reads at step s of proposal n: the target pose ``poses[n, s]`` (x, y, heading) with its
    ``sin`` / ``cos``, the fitted ``speed`` ten steps ahead, and the curvature ``moments[n, s]``: sum u_k kappa_k
    (linear: v, a) and sum_{j<k} kappa_j u_j u_k (quadratic: vv, va, aa) over the lookahead."""

    poses: np.ndarray  # (N, S + 1, 3): the targets themselves, the last one read only by the fits
    sin: np.ndarray  # (N, S)
    cos: np.ndarray  # (N, S)
    speed: np.ndarray  # (N, S)
    moments: np.ndarray  # (N, S, 5)


@lru_cache(maxsize=8)
def _lookahead_terms(horizon: int, dt: float, wheel_base: float) -> tuple[np.ndarray, LateralTerms]:
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
    horizon_time = horizon * dt
    gain = -1.0 / (horizon_time * Q_LONGITUDINAL * horizon_time + R_LONGITUDINAL) * horizon_time * Q_LONGITUDINAL
    fixed = LateralTerms(
        gain,
        dt * horizon,
        dt**2 * k.sum(),
        *pair_terms.sum(0).tolist(),
        # response to a unit steering rate: steering k dt before step k, heading sum_k u_k k dt / L, lateral error
        *(dt / wheel_base * np.array([dt * k.sum(), dt**2 * (k * k).sum()])).tolist(),
        *(dt / wheel_base * (first[:, None] * pair_terms).sum(0)).tolist(),
        1.0 / wheel_base,
    )
    return curvature, fixed


def tracking_reference(targets: np.ndarray, dt: float, wheel_base: float) -> tuple[TrackingReference, LateralTerms]:
    """Targets ``(N, T, 3)`` -> what the tracker reads at each of the T - 1 steps, and the fixed terms."""
    steps = np.diff(targets, axis=1)
    headings = targets[:, :-1, 2]
    sin, cos = np.sin(headings), np.cos(headings)  # the fit's projection and the tracker's target frames
    projected = cos * steps[..., 0] + sin * steps[..., 1]
    num_fits = steps.shape[1]
    speed = row_products(projected, speed_fit_matrix(num_fits, dt).T)
    curvature = curvature_profile(normalize_angle(steps[..., 2]), speed, dt)
    weights, fixed = _lookahead_terms(TRACKING_HORIZON, dt, wheel_base)
    ahead = np.minimum(np.arange(num_fits) + TRACKING_HORIZON, num_fits - 1)  # the reference speed's pose
    reference_speed = np.take(speed, ahead, axis=1)  # np.take: far faster than fancy indexing
    return TrackingReference(targets, sin, cos, reference_speed, _lookahead_moments(curvature, weights)), fixed


@njit(cache=True)
def track(
    reference: TrackingReference, n: int, s: int, x: float, y: float, heading: float, speed: float, steering: float,
    terms: LateralTerms,
) -> tuple[float, float]:  # fmt: skip
    """Acceleration and steering-rate commands of proposal ``n`` at step ``s`` for its ego pose, speed and steering.

    Lateral problem unrolled over the lookahead (u_k = v_k dt, steering s constant, U_k / W_k the sums of u_j and
    u_j kappa_j over j < k): heading error h_k = h + s U_k / L - W_k, lateral error e + sum_k u_k h_k
    = e + h U + s / L sum_{j<k} u_j u_k - sum_{j<k} kappa_j u_j u_k; a unit steering rate adds k dt to the
    steering angle before step k. Q_LATERAL's lateral-error weight is 1 and its steering weight 0, so neither
    appears below. The stopping P controller replaces the LQR where reference and ego speed are both <= 0.2 m/s.
    """
    target_x, target_y, target_heading = reference.poses[n, s, 0], reference.poses[n, s, 1], reference.poses[n, s, 2]
    sin, cos, reference_speed = reference.sin[n, s], reference.cos[n, s], reference.speed[n, s]
    moment = reference.moments[n, s]
    lateral_error = (y - target_y) * cos - (x - target_x) * sin
    heading_error = normalize_angle(heading - target_heading)
    accel = terms.accel_gain * (speed - reference_speed)

    u_sum = terms.u_sum_v * speed + terms.u_sum_a * accel
    steer_per_length = steering * terms.inverse_wheel_base
    curvature_sum = moment[0] * speed + moment[1] * accel
    final_heading = normalize_angle(heading_error + steer_per_length * u_sum - curvature_sum)
    pairs = (terms.pairs_vv * speed + terms.pairs_va * accel) * speed + terms.pairs_aa * accel * accel
    curvature_pairs = (moment[2] * speed + moment[3] * accel) * speed + moment[4] * accel * accel
    final_error = lateral_error + heading_error * u_sum + steer_per_length * pairs - curvature_pairs
    input_heading = terms.input_heading_v * speed + terms.input_heading_a * accel
    input_error = (
        terms.input_error_vv * speed + terms.input_error_va * accel
    ) * speed + terms.input_error_aa * accel * accel
    weighted_heading = Q_LATERAL[1] * input_heading
    denominator = input_error * input_error + weighted_heading * input_heading + R_LATERAL
    steering_rate = (input_error * final_error + weighted_heading * final_heading) / denominator
    if reference_speed <= STOPPING_VELOCITY and speed <= STOPPING_VELOCITY:
        return -STOPPING_GAIN * (speed - reference_speed), 0.0
    return accel, -steering_rate
