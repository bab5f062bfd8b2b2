"""NAVSIM's agent output grid (nuPlan's ``TrajectorySampling(time_horizon=4, interval_length=0.5)``) for the
scorers and the submission writer alike, in a module free of the scorers' shapely imports."""

import numpy as np

from lead_s2r.geometry import resample
from lead_s2r.predictions import Prediction, PredictionError

INTERVAL = 0.5
NUM_POSES = 8
NAVSIM_GRID = INTERVAL * np.arange(1, NUM_POSES + 1)


def require_headings(prediction: Prediction) -> None:
    if np.isnan(prediction.yaw).any():
        raise PredictionError(f"prediction {prediction.key!r}: yaw is NaN; NAVSIM needs a heading at every pose")


def navsim_poses(prediction: Prediction) -> np.ndarray:
    """(8, 3) float64 (x, y, heading) on :data:`NAVSIM_GRID`, resampled with the ego at the origin at t = 0 as the
    first knot; an error names the key if the prediction has no heading or ends before 4 s."""
    require_headings(prediction)
    t = np.asarray(prediction.t, np.float64)
    knots = np.vstack([np.zeros(3), np.column_stack([prediction.xy, prediction.yaw])])
    values, inside = resample(np.r_[0.0, t], knots, NAVSIM_GRID, angle_columns=(2,))
    if not inside.all():
        raise PredictionError(
            f"prediction {prediction.key!r}: ends at {t[-1]:g} s, NAVSIM needs {NUM_POSES} poses up to "
            f"{NAVSIM_GRID[-1]:g} s (predictions are never extrapolated)"
        )
    return values
