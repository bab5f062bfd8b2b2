"""Comfort (C) of NAVSIM v1.1, ``pdm_comfort_metrics.ego_is_comfortable``, and its feature extractors for v2's
history comfort and two-frame extended comfort (which change windows and the acceleration frame, not the maths).

Savitzky-Golay filtering and differentiation are scipy's ``savgol_filter`` (mode "interp"), as in NAVSIM. Every
feature is rounded to 8 decimals. Official behaviours reproduced on purpose:

* v1.1 filters the accelerations with a window of the whole horizon (41 states), but the jerk is the derivative of
  an acceleration smoothed with the *default* window 8 (``_extract_ego_jerk`` does not pass its window on), the
  derivative itself using the 41-state window.
* Yaw rate and yaw acceleration always use a window of 5 (``_extract_ego_yaw_rate`` ignores its window argument);
  yaw acceleration is the order-3 second derivative. Headings are unwrapped with nuPlan's ``_phase_unwrap``
  (``round`` of the jump over 2 pi), not ``np.unwrap``.
* Accelerations are the rear-axle body-frame ``ACCELERATION_X/Y`` of the states (v2 passes centre-frame ones).
* Bounds are strict and must hold at every step: -4.05 < a_lon < 2.40 m/s^2, |a_lat| < 4.89 m/s^2,
  |jerk| < 8.37 m/s^3, |jerk_lon| < 4.13 m/s^3, |yaw accel| < 1.93 rad/s^2, |yaw rate| < 0.95 rad/s.
* The derivative step is the mean of the time differences (``np.diff(t).mean()``).

A Savitzky-Golay filter of fixed length, window, order and step is a linear map, so it is taken once from scipy as a
``(T, T)`` matrix (the filter applied to the identity) and then applied to all proposals by one product: the same
operator as ``savgol_filter`` row by row, up to the order of floating-point additions.
"""

from functools import lru_cache

import numpy as np
from scipy.signal import savgol_filter

from lead_s2r.scoring.pdm.state import StateIndex

MIN_LON_ACCEL, MAX_LON_ACCEL = -4.05, 2.40  # [m/s^2]
MAX_ABS_LAT_ACCEL = 4.89  # [m/s^2]
MAX_ABS_JERK = 8.37  # [m/s^3]
MAX_ABS_LON_JERK = 4.13  # [m/s^3]
MAX_ABS_YAW_ACCEL = 1.93  # [rad/s^2]
MAX_ABS_YAW_RATE = 0.95  # [rad/s]
DECIMALS = 8
ACCEL_WINDOW = 8  # the extractor default that the jerk's smoothing keeps
YAW_WINDOW = 5


@lru_cache(maxsize=64)
def _savgol_matrix(length: int, window_length: int, polyorder: int, deriv: int, delta: float) -> np.ndarray:
    identity = np.eye(length)
    return savgol_filter(identity, window_length, polyorder, deriv=deriv, delta=delta, axis=0, mode="interp")


def savgol(values: np.ndarray, window_length: int, polyorder: int, deriv: int = 0, delta: float = 1.0) -> np.ndarray:
    """``scipy.signal.savgol_filter(values, ..., axis=-1, mode="interp")`` for a batch ``(..., T)`` of signals."""
    return values @ _savgol_matrix(values.shape[-1], window_length, polyorder, deriv, delta).T


def acceleration(states: np.ndarray, coordinate: str, window: int = ACCEL_WINDOW, poly_order: int = 2) -> np.ndarray:
    """Smoothed acceleration ``(N, T)``: ``coordinate`` "x", "y" or "magnitude" of ``ACCELERATION_X/Y``."""
    ax, ay = states[..., StateIndex.ACCELERATION_X], states[..., StateIndex.ACCELERATION_Y]
    if coordinate == "x":
        signal = ax
    elif coordinate == "y":
        signal = ay
    elif coordinate == "magnitude":
        signal = np.hypot(ax, ay)
    else:
        raise ValueError(f"acceleration coordinate {coordinate!r}: use 'x', 'y' or 'magnitude'")
    smoothed = savgol(signal, window_length=min(window, states.shape[-2]), polyorder=poly_order)
    return np.round(smoothed, DECIMALS)


def derivative(
    values: np.ndarray, times: np.ndarray, window: int = 5, poly_order: int = 2, order: int = 1
) -> np.ndarray:
    """nuPlan ``_approximate_derivatives``: Savitzky-Golay derivative of ``values (N, T)`` over equally spaced times."""
    window = min(window, len(times))
    if not poly_order < window:
        raise ValueError(f"Savitzky-Golay polynomial order {poly_order} needs a window longer than {window}")
    step = np.diff(times)
    if not (step > 0).all():
        raise ValueError("comfort times must increase strictly")
    return savgol(values, window_length=window, polyorder=poly_order, deriv=order, delta=float(step.mean()))


def jerk(
    states: np.ndarray, coordinate: str, times: np.ndarray, window: int, accel_window: int = ACCEL_WINDOW
) -> np.ndarray:
    """Jerk ``(N, T)``: derivative (``window``, order 2) of the acceleration smoothed with ``accel_window``."""
    return np.round(derivative(acceleration(states, coordinate, accel_window), times, window), DECIMALS)


def phase_unwrap(headings: np.ndarray) -> np.ndarray:
    """nuPlan ``_phase_unwrap``: subtract 2 pi times the running sum of the rounded jumps."""
    two_pi = 2.0 * np.pi
    adjustments = np.zeros_like(headings)
    adjustments[..., 1:] = np.cumsum(np.round(np.diff(headings, axis=-1) / two_pi), axis=-1)
    return headings - two_pi * adjustments


def yaw_rate(states: np.ndarray, times: np.ndarray, window: int = YAW_WINDOW) -> np.ndarray:
    """Yaw rate ``(N, T)``: first derivative (order 2) of the unwrapped heading."""
    heading = phase_unwrap(states[..., StateIndex.HEADING])
    return np.round(derivative(heading, times, window, poly_order=2, order=1), DECIMALS)


def yaw_acceleration(states: np.ndarray, times: np.ndarray, window: int = YAW_WINDOW) -> np.ndarray:
    """Yaw acceleration ``(N, T)``: second derivative (order 3) of the unwrapped heading."""
    heading = phase_unwrap(states[..., StateIndex.HEADING])
    return np.round(derivative(heading, times, window, poly_order=3, order=2), DECIMALS)


def _within(values: np.ndarray, low: float, high: float) -> np.ndarray:
    return ((values > low) & (values < high)).all(axis=-1)


def comfort_checks(states: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``(N, 6)`` v1.1 checks: lon accel, lat accel, jerk, lon jerk, yaw accel, yaw rate (``ego_is_comfortable``)."""
    horizon = states.shape[-2]
    return np.stack(
        [
            _within(acceleration(states, "x", horizon), MIN_LON_ACCEL, MAX_LON_ACCEL),
            _within(acceleration(states, "y", horizon), -MAX_ABS_LAT_ACCEL, MAX_ABS_LAT_ACCEL),
            _within(jerk(states, "magnitude", times, horizon), -MAX_ABS_JERK, MAX_ABS_JERK),
            _within(jerk(states, "x", times, horizon), -MAX_ABS_LON_JERK, MAX_ABS_LON_JERK),
            _within(yaw_acceleration(states, times), -MAX_ABS_YAW_ACCEL, MAX_ABS_YAW_ACCEL),
            _within(yaw_rate(states, times), -MAX_ABS_YAW_RATE, MAX_ABS_YAW_RATE),
        ],
        axis=-1,
    )


def comfort(states: np.ndarray, interval: float = 0.1) -> np.ndarray:
    """C ``(N,)`` in {0, 1} of states ``(N, T, 11)`` at ``interval``: 1 when all six checks hold at every step."""
    times = np.arange(0, states.shape[-2]).astype(np.float64) * interval
    return comfort_checks(states, times).all(axis=-1).astype(np.float64)
