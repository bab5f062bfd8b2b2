"""Route checkpoints of one sample on the planner's spatial path (LEAD's ``smooth_path``: 2.5 m ahead, then every
metre), and the NaN-to-zero cast every resampled trajectory label goes through."""

import numpy as np
import torch

from lead_s2r.geometry import resample

#: Route checkpoints start this far ahead, then come every metre (LEAD's ``smooth_path``).
ROUTE_START_M = 2.5


def route_checkpoints(route: np.ndarray, count: int) -> dict[str, torch.Tensor]:
    """Points along the route at 2.5 m, 3.5 m, ... of arc length from the ego (the origin); masked past its end."""
    route = np.vstack([np.zeros((1, 2)), np.asarray(route, np.float64)])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=1))])
    keep = np.concatenate([[True], np.diff(arc) > 1e-6])  # repeated points would stall the interpolation
    targets = ROUTE_START_M + np.arange(count, dtype=np.float64)
    if keep.sum() < 2:
        points, valid = np.zeros((count, 2)), np.zeros(count, bool)
    else:
        points, valid = resample(arc[keep], route[keep], targets)
    return {
        "route": torch.from_numpy(nan_to_zero(points)),
        "route_valid": torch.from_numpy(valid),
    }


def nan_to_zero(values: np.ndarray) -> np.ndarray:
    """float64 ``values`` (resampled, NaN where masked) as float32 with NaN as 0.

    Equal to ``np.nan_to_num(values).astype(np.float32)`` (whose +-float64 max for +-inf round to +-inf in float32)
    in three numpy calls instead of a dozen: this runs three times per sample on arrays of a few dozen numbers."""
    out = values.astype(np.float32)
    out[np.isnan(out)] = 0.0
    return out
