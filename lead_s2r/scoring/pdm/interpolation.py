"""Trajectories to the 41 tracker targets (t = 0, 0.1, .., 4.0 s), as NAVSIM's ``pdm_score`` builds them.

NAVSIM (``evaluate/pdm_score.py``: ``transform_trajectory`` + ``get_trajectory_as_array``) prepends the initial ego
pose at t = 0 to the agent's poses, wraps them in a nuPlan ``InterpolatedTrajectory`` and samples it every 0.1 s.
That is linear interpolation in x and y, and in the heading after ``np.unwrap`` over the knots, the result wrapped
to [-pi, pi) (nuPlan ``AngularInterpolator`` + ``principal_value``). Sample times past the last knot are clipped
to it, so a trajectory shorter than 4 s holds its last pose. The PDM-Closed reference goes through the same
sampling (its knots are every 0.1 s from t = 0, so the first 41 knots come back, up to the quirk below).

Reproduced on purpose (``t0_us``): nuPlan keeps times as integer microseconds, and NAVSIM gets them by
truncating float seconds: a knot k of the agent sits at ``int((k * interval + t0_us * 1e-6) * 1e6)`` and a sample
at ``int((j * 0.1 + t0_us * 1e-6) * 1e6)``. At real timestamps (~1.6e9 s, float64 spacing ~2.4e-7 s) both land up
to 1 us early, which moves a target by up to ~1e-5 m at 10 m/s. Pass the scene's timestamp ``t0_us`` to
reproduce the official targets exactly; without it the times are the exact multiples of the intervals.
The pose of the first knot (0, 0, 0) is the ego rear axle; all poses are in the ego frame at t0.
"""

import numpy as np

#: NAVSIM's ``proposal_sampling``: the simulator tracks 40 steps of 0.1 s (41 states with t = 0).
PROPOSAL_INTERVAL = 0.1
PROPOSAL_STEPS = 40


def truncated_us(times_s: np.ndarray, t0_us: int | None) -> np.ndarray:
    """Microseconds after t0 of times in seconds after t0, as nuPlan's ``TimePoint(int(t_s * 1e6))`` gets them."""
    if t0_us is None:
        return np.round(np.asarray(times_s, np.float64) * 1e6).astype(np.int64)
    absolute = np.asarray(times_s, np.float64) + t0_us * 1e-6
    return (absolute * 1e6).astype(np.int64) - t0_us


def sample_times_us(t0_us: int | None = None) -> np.ndarray:
    """The 41 sample times of ``get_trajectory_as_array`` in microseconds after t0 (before clipping)."""
    horizon = PROPOSAL_STEPS * PROPOSAL_INTERVAL
    return truncated_us(np.arange(0.0, horizon + PROPOSAL_INTERVAL, PROPOSAL_INTERVAL), t0_us)


def interp1d(times: np.ndarray, values: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """scipy ``interp1d``'s linear arithmetic (left neighbour by ``searchsorted``, slope times offset plus left value)
    of ``values (..., T, D)`` at knot times ``times (T,)`` (increasing), sampled at ``samples (S,)`` -> ``(..., S, D)``;
    the headings (column 2) are unwrapped along the knots first and left unwrapped."""
    hi = np.clip(np.searchsorted(times, samples, side="left"), 1, len(times) - 1)
    lo = hi - 1
    values = np.array(values, np.float64)
    values[..., 2] = np.unwrap(values[..., 2], axis=-1)
    # np.take: the same rows, far faster than fancy indexing
    high, low = np.take(values, hi, axis=-2), np.take(values, lo, axis=-2)
    slope = (high - low) / (times[hi] - times[lo]).astype(np.float64)[:, None]
    return slope * (samples - times[lo]).astype(np.float64)[:, None] + low


def interpolate_knots(knot_us: np.ndarray, knots: np.ndarray, sample_us: np.ndarray) -> np.ndarray:
    """Poses ``(..., T, 3)`` at knot times ``(T,)`` (us, increasing) sampled at ``sample_us (S,)`` -> ``(..., S, 3)``:
    :func:`interp1d` with the samples clipped to the knot span and the headings wrapped to [-pi, pi) after."""
    knot_us = np.asarray(knot_us, np.int64)
    out = interp1d(knot_us, knots, np.clip(sample_us, knot_us[0], knot_us[-1]))
    out[..., 2] = (out[..., 2] + np.pi) % (2 * np.pi) - np.pi
    return out


def _require_finite(poses: np.ndarray, name: str) -> None:
    if not np.isfinite(poses).all():
        bad = np.unique(np.argwhere(~np.isfinite(poses))[:, :-1], axis=0)
        raise ValueError(f"{name}: NaN or infinite pose values at index {bad[:5].tolist()} (first 5); remove them")


def interpolate_proposals(proposals: np.ndarray, interval: float, t0_us: int | None = None) -> np.ndarray:
    """Ego-frame poses ``(N, K, 3)`` at t = interval * (k + 1) -> the 41 tracker targets ``(N, 41, 3)``."""
    proposals = np.asarray(proposals, np.float64)
    if proposals.ndim != 3 or proposals.shape[-1] != 3 or proposals.shape[1] < 1:
        raise ValueError(f"proposals: expected shape (N, K >= 1, 3) of x, y, heading, got {proposals.shape}")
    if not interval > 0:
        raise ValueError(f"interval: expected a positive number of seconds, got {interval}")
    _require_finite(proposals, "proposals")
    count, num_poses, _ = proposals.shape
    # the initial pose at 0, the proposal's at nuPlan's ``_get_fixed_timesteps``: arange(0, K * dt, dt) + dt seconds
    times = np.arange(0.0, num_poses * interval, interval)[:num_poses] + interval
    knot_us = np.concatenate([[0], truncated_us(times, t0_us)])
    knots = np.concatenate([np.zeros((count, 1, 3)), proposals], axis=1)
    return interpolate_knots(knot_us, knots, sample_times_us(t0_us))


def interpolate_reference(reference: np.ndarray, t0_us: int | None = None) -> np.ndarray:
    """A reference ``(M, 3)`` at t = 0.1 s * m from t = 0 (pose 0 = the ego, PDM-Closed's layout) -> ``(41, 3)``.

    The knots are at exact microseconds (PDM-Closed's states carry integer time points); only the samples are
    truncated, so with ``t0_us`` a sample may fall 1 us before its knot, as in NAVSIM."""
    reference = np.asarray(reference, np.float64)
    if reference.ndim != 2 or reference.shape[-1] != 3 or len(reference) < 2:
        raise ValueError(f"reference: expected shape (M >= 2, 3) of x, y, heading from t = 0, got {reference.shape}")
    _require_finite(reference, "reference")
    knot_us = np.round(np.arange(len(reference)) * PROPOSAL_INTERVAL * 1e6).astype(np.int64)
    return interpolate_knots(knot_us, reference, sample_times_us(t0_us))
