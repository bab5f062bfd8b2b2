"""Comfort (C) of NAVSIM v1.1 and history comfort (HC) of v2.2 (``pdm_comfort_metrics.ego_is_comfortable``), and the
feature extractor of v2's two-frame extended comfort (``extract_features``): the versions change windows, the
acceleration frame and the states read, not the maths.

Savitzky-Golay filtering and differentiation are scipy's ``savgol_filter`` (mode "interp"), as in NAVSIM. Every
feature is rounded to 8 decimals. Official behaviours reproduced on purpose:

* v1.1 filters the accelerations with a window of the whole horizon (41 states), but the jerk is the derivative of
  an acceleration smoothed with the *default* window 8 (``_extract_ego_jerk`` does not pass its window on), the
  derivative itself using the 41-state window. v2 uses window 8 for the accelerations and 15 for the jerk's
  derivative (``min(15, T)``).
* Yaw rate and yaw acceleration always use a window of 5 (``_extract_ego_yaw_rate`` ignores its window argument);
  the comfort checks' yaw acceleration is the order-3 second derivative, EC's the order-2 one. Headings are
  unwrapped with nuPlan's ``_phase_unwrap`` (``round`` of the jump over 2 pi), not ``np.unwrap``.
* v1.1 reads the rear-axle body-frame ``ACCELERATION_X/Y``. v2's lon/lat accelerations and lon jerk are those of the
  box centre (``state_array_to_center_state_array``: nuPlan's ``get_acceleration_shifted``, which adds
  ``d * (yaw_rate^2 + yaw_accel)`` along the displacement ``(d, 0)``, d = rear axle to centre); the jerk magnitude
  (and EC's acceleration) stays on the rear axle.
* HC prepends the logged past to the 41 simulated states: the past trajectory sampled every 0.1 s from its first time up
  to (excluding) its last, then the last sample dropped too (``arange(start, end, 0.1)[:-1]``: 14 states -1.5..-0.2 s,
  -0.1 s is missing), linear in position and dynamics, angular in heading, yaw rate and yaw acceleration 0 (nuPlan's
  interpolated ``EgoState``). The whole array gets the time base ``arange(T) * 0.1``. Without a past, HC is 1.
* Bounds are strict and must hold at every step: -4.05 < a_lon < 2.40 m/s^2, |a_lat| < 4.89 m/s^2,
  |jerk| < 8.37 m/s^3, |jerk_lon| < 4.13 m/s^3, |yaw accel| < 1.93 rad/s^2, |yaw rate| < 0.95 rad/s.
* The derivative step is the mean of the time differences (``np.diff(t).mean()``).

A Savitzky-Golay filter of fixed length, window, order and step is a linear map, so it is taken once from scipy as a
``(T, T)`` matrix (the filter applied to the identity) and then applied to every proposal by its own product
(``row_products``): the same operator as ``savgol_filter`` row by row, up to the order of floating-point additions.
"""

from functools import lru_cache

import numpy as np
from scipy.signal import savgol_filter

from lead_s2r.scoring.pdm.interpolation import interpolate_knots
from lead_s2r.scoring.pdm.rowwise import row_products
from lead_s2r.scoring.pdm.state import STATE_SIZE, StateIndex
from lead_s2r.scoring.pdm.vehicle import VehicleParameters

MIN_LON_ACCEL, MAX_LON_ACCEL = -4.05, 2.40  # [m/s^2]
MAX_ABS_LAT_ACCEL = 4.89  # [m/s^2]
MAX_ABS_JERK = 8.37  # [m/s^3]
MAX_ABS_LON_JERK = 4.13  # [m/s^3]
MAX_ABS_YAW_ACCEL = 1.93  # [rad/s^2]
MAX_ABS_YAW_RATE = 0.95  # [rad/s]
DECIMALS = 8
ACCEL_WINDOW = 8  # the extractor default that the jerk's smoothing keeps
YAW_WINDOW = 5
V2_JERK_WINDOW = 15
#: HC's past sampling step [us] (``int(0.1 * 1e6)``)
PAST_STEP_US = 100_000


@lru_cache(maxsize=64)
def _savgol_matrix(length: int, window_length: int, polyorder: int, deriv: int, delta: float) -> np.ndarray:
    identity = np.eye(length)
    return savgol_filter(identity, window_length, polyorder, deriv=deriv, delta=delta, axis=0, mode="interp")


def savgol(values: np.ndarray, window_length: int, polyorder: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """``scipy.signal.savgol_filter(values, ..., axis=-1, mode="interp")`` for a batch ``(..., T)`` of signals."""
    return row_products(values, _savgol_matrix(values.shape[-1], window_length, polyorder, deriv, delta).T)


def smoothed(signal: np.ndarray, window: int) -> np.ndarray:
    """A Savitzky-Golay smoothed acceleration ``(N, T)`` (order 2, the window at most T), rounded."""
    return np.round(savgol(signal, window_length=min(window, signal.shape[-1]), polyorder=2), DECIMALS)


def derivative(
    values: np.ndarray, times: np.ndarray, window: int = YAW_WINDOW, poly_order: int = 2, order: int = 1
) -> np.ndarray:
    """nuPlan ``_approximate_derivatives``, rounded: Savitzky-Golay derivative of ``values (N, T)`` over equally spaced
    times (yaw rate by default)."""
    window = min(window, len(times))
    if not poly_order < window:
        raise ValueError(f"Savitzky-Golay polynomial order {poly_order} needs a window longer than {window}")
    step = np.diff(times)
    if not (step > 0).all():
        raise ValueError("comfort times must increase strictly")
    derived = savgol(values, window_length=window, polyorder=poly_order, deriv=order, delta=float(step.mean()))
    return np.round(derived, DECIMALS)


def _magnitude(states: np.ndarray) -> np.ndarray:
    """The magnitude ``(N, T)`` of the rear-axle ``ACCELERATION_X/Y``."""
    return np.hypot(states[..., StateIndex.ACCELERATION_X], states[..., StateIndex.ACCELERATION_Y])


def phase_unwrap(headings: np.ndarray) -> np.ndarray:
    """nuPlan ``_phase_unwrap``: subtract 2 pi times the running sum of the rounded jumps."""
    two_pi = 2.0 * np.pi
    adjustments = np.zeros_like(headings)
    adjustments[..., 1:] = np.cumsum(np.round(np.diff(headings, axis=-1) / two_pi), axis=-1)
    return headings - two_pi * adjustments


def _within(values: np.ndarray, low: float, high: float) -> np.ndarray:
    return ((values > low) & (values < high)).all(axis=-1)


def comfort_checks(
    states: np.ndarray, times: np.ndarray, lon_lat: np.ndarray, accel_window: int, jerk_window: int
) -> np.ndarray:
    """``(N, 6)`` checks: lon accel, lat accel, jerk, lon jerk, yaw accel, yaw rate (``ego_is_comfortable``), the
    accelerations read from the states ``lon_lat``: v1.1 the rear-axle states themselves and windows of the whole
    horizon (:func:`comfort`), v2 the centre-frame ones and windows 8 and 15 (:func:`history_comfort_checks`)."""
    lon, lat = lon_lat[..., StateIndex.ACCELERATION_X], lon_lat[..., StateIndex.ACCELERATION_Y]
    # computed once where two checks read the same numbers: the longitudinal acceleration where the jerk smooths it
    # with the same window (v2), the unwrapped heading
    lon_accel = smoothed(lon, accel_window)
    smoothed_lon = lon_accel if accel_window == ACCEL_WINDOW else smoothed(lon, ACCEL_WINDOW)
    heading = phase_unwrap(states[..., StateIndex.HEADING])
    jerk = derivative(smoothed(_magnitude(states), ACCEL_WINDOW), times, jerk_window)
    return np.stack(
        [
            _within(lon_accel, MIN_LON_ACCEL, MAX_LON_ACCEL),
            _within(smoothed(lat, accel_window), -MAX_ABS_LAT_ACCEL, MAX_ABS_LAT_ACCEL),
            _within(jerk, -MAX_ABS_JERK, MAX_ABS_JERK),
            _within(derivative(smoothed_lon, times, jerk_window), -MAX_ABS_LON_JERK, MAX_ABS_LON_JERK),
            _within(derivative(heading, times, poly_order=3, order=2), -MAX_ABS_YAW_ACCEL, MAX_ABS_YAW_ACCEL),
            _within(derivative(heading, times), -MAX_ABS_YAW_RATE, MAX_ABS_YAW_RATE),
        ],
        axis=-1,
    )


def comfort(states: np.ndarray, interval: float = 0.1) -> np.ndarray:
    """C ``(N,)`` in {0, 1} of states ``(N, T, 11)`` at ``interval``: 1 when all six checks hold at every step."""
    horizon = states.shape[-2]
    times = np.arange(0, horizon).astype(np.float64) * interval
    return comfort_checks(states, times, states, horizon, horizon).all(axis=-1).astype(np.float64)


def center_frame(states: np.ndarray, vehicle: VehicleParameters) -> np.ndarray:
    """States with the accelerations moved from the rear axle to the box centre (nuPlan ``get_acceleration_shifted``
    with displacement ``(d, 0)``: ``a + d * (yaw_rate^2 + yaw_accel)`` on both components, so only x changes)."""
    out = np.array(states, np.float64)
    shift = vehicle.rear_axle_to_center * (
        states[..., StateIndex.ANGULAR_VELOCITY] ** 2 + states[..., StateIndex.ANGULAR_ACCELERATION]
    )
    out[..., StateIndex.ACCELERATION_X] += shift
    return out


def past_states(ego_past: np.ndarray) -> np.ndarray:
    """The logged past ``(P, 8)`` (t, x, y, heading, vx, vy, ax, ay; t increasing, the last row at t = 0) as HC's
    ``(H, 11)`` states at 0.1 s steps, the last two samples before t = 0 left out (module docstring)."""
    ego_past = np.asarray(ego_past, np.float64)
    if ego_past.ndim != 2 or ego_past.shape[-1] != 8 or len(ego_past) < 2:
        raise ValueError(f"ego_past: expected (P >= 2, 8) rows (t, x, y, yaw, vx, vy, ax, ay), got {ego_past.shape}")
    knot_us = np.round(ego_past[:, 0] * 1e6).astype(np.int64)
    if not (np.diff(knot_us) > 0).all():
        raise ValueError("ego_past: times must increase strictly")
    sample_us = np.arange(knot_us[0], knot_us[-1], PAST_STEP_US, dtype=np.int64)[:-1]
    states = np.zeros((len(sample_us), STATE_SIZE))
    states[:, : StateIndex.HEADING + 1] = interpolate_knots(knot_us, ego_past[:, 1:4], sample_us)
    for column, source in zip(range(StateIndex.VELOCITY_X, StateIndex.ACCELERATION_Y + 1), range(4, 8), strict=True):
        states[:, column] = np.interp(sample_us, knot_us, ego_past[:, source])
    return states


def history_comfort_checks(
    states: np.ndarray, ego_past: np.ndarray, vehicle: VehicleParameters, interval: float = 0.1
) -> np.ndarray:
    """v2's ``(N, 6)`` comfort checks of the logged past (:func:`past_states`) followed by states ``(N, T, 11)``."""
    history = past_states(ego_past)
    padded = np.concatenate([np.broadcast_to(history, (len(states), *history.shape)), states], axis=1)
    times = np.arange(0, padded.shape[1]).astype(np.float64) * interval
    return comfort_checks(padded, times, center_frame(padded, vehicle), ACCEL_WINDOW, V2_JERK_WINDOW)


def history_comfort(
    states: np.ndarray, ego_past: np.ndarray | None, vehicle: VehicleParameters, interval: float = 0.1
) -> np.ndarray:
    """HC ``(N,)`` in {0, 1}: all six v2 checks over past and simulation hold at every step; 1 without a past."""
    if ego_past is None or len(ego_past) == 0:
        return np.ones(len(states))
    return history_comfort_checks(states, ego_past, vehicle, interval).all(axis=-1).astype(np.float64)


def extended_comfort_features(states: np.ndarray, times: np.ndarray) -> dict[str, np.ndarray]:
    """EC's features of states ``(..., T, 11)`` (``extract_features``): rear-axle acceleration magnitude (window 8),
    its jerk (window 15), yaw rate and the order-2 yaw acceleration (window 5)."""
    heading = phase_unwrap(states[..., StateIndex.HEADING])
    acceleration = smoothed(_magnitude(states), ACCEL_WINDOW)
    return {
        "acceleration": acceleration,
        "jerk": derivative(acceleration, times, V2_JERK_WINDOW),
        "yaw_rate": derivative(heading, times),
        "yaw_accel": derivative(heading, times, order=2),
    }
