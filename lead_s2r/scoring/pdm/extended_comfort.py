"""EC, NAVSIM v2's two-frame extended comfort: do two plans made 0.5 s apart agree where their simulations overlap?

EC compares *simulated* ego states (41 x 11 at 0.1 s) of a frame with those of the frame 0.5 s earlier
(``scene_aggregator.py::_compute_two_frame_comfort``). The offset is ``round(interval / 0.1)``, which is 5, and the
overlap is ``current[:-5]`` against ``previous[5:]``: 36 states each. The official code asserts ``0 < interval < 0.55``.

The trap: the comfort features (Savitzky-Golay filtered acceleration magnitude, its jerk, yaw rate and yaw
acceleration; ``pdm_comfort_metrics.extract_features``) are extracted on the two 36-state *slices*, on a time base
``arange(36) * 0.1``, not taken from the full 41 states and then cut: the filters' edge windows differ, so cutting
afterwards gives other numbers. The RMS of the per-step differences must keep the non-strict :data:`THRESHOLDS`.
"""

from collections.abc import Callable, Mapping

import numpy as np

#: RMS bounds of the per-step feature differences (``pdm_comfort_metrics``), all inclusive.
THRESHOLDS = {"acceleration": 0.7, "jerk": 0.5, "yaw_rate": 0.1, "yaw_accel": 0.1}
#: Longest gap between two frames that still pair (the official assert and ``infer_start_adjacent_mapping``).
MAX_INTERVAL_S = 0.55

#: states (T, 11), time (T,) -> {feature name: (T,) values} for the names in :data:`THRESHOLDS`.
FeatureExtractor = Callable[[np.ndarray, np.ndarray], Mapping[str, np.ndarray]]


def overlap(
    current: np.ndarray, previous: np.ndarray, interval: float, step: float = 0.1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The overlapping parts of two frames' simulated states and their time base: ``current[:-k]``,
    ``previous[k:]`` and ``arange(T - k) * step``, with ``k = round(interval / step)``. ``interval`` is the current
    frame's start time minus the previous frame's."""
    if not 0.0 < interval < MAX_INTERVAL_S:
        raise ValueError(f"extended comfort: frames {interval:.3f} s apart; they must be 0 < dt < {MAX_INTERVAL_S} s")
    current, previous = np.asarray(current, np.float64), np.asarray(previous, np.float64)
    if current.shape != previous.shape:
        raise ValueError(f"extended comfort: state arrays differ in shape ({current.shape} vs {previous.shape})")
    offset = round(interval / step)
    if not 0 < offset < len(current):
        raise ValueError(f"extended comfort: an offset of {offset} steps leaves no overlap of {len(current)} states")
    return current[:-offset], previous[offset:], np.arange(len(current) - offset) * step


def rms_differences(current: Mapping[str, np.ndarray], previous: Mapping[str, np.ndarray]) -> dict[str, float]:
    """RMS over time of ``current[name] - previous[name]`` for each feature in :data:`THRESHOLDS`."""
    out = {}
    for name in THRESHOLDS:
        if name not in current or name not in previous:
            raise KeyError(f"extended comfort: feature {name!r} is missing (needed: {', '.join(THRESHOLDS)})")
        difference = np.asarray(current[name], np.float64) - np.asarray(previous[name], np.float64)
        out[name] = float(np.sqrt(np.mean(difference**2)))
    return out


def is_extended_comfortable(current: Mapping[str, np.ndarray], previous: Mapping[str, np.ndarray]) -> bool:
    """EC of one pair from the features of its overlapping states: every RMS difference within its bound."""
    rms = rms_differences(current, previous)
    return all(rms[name] <= bound for name, bound in THRESHOLDS.items())


def two_frame_extended_comfort(
    current: np.ndarray, previous: np.ndarray, interval: float, features: FeatureExtractor
) -> float:
    """EC (1.0 or 0.0) of a frame whose simulated states are ``current`` against the frame ``interval`` seconds
    earlier, with ``features`` extracting the comfort features of each overlapping slice."""
    now, before, time = overlap(current, previous, interval)
    return float(is_extended_comfortable(features(now, time), features(before, time)))
