"""LiDAR points -> the BEV hit-count raster the backbone reads, on the loader's CPU (the device does the same with
:func:`~lead_s2r.data.device_inputs.rasterize_points` when the points are left for it).

A LEAD frame has about 60,000 points, so every pass over them and every large temporary shows: the fractional row
and column stay in the points' dtype (float32: a point lands in the cell it always did), the in-grid points are
picked once and their cell index is formed in that dtype (exact below 2**24 cells, which :func:`_lidar_cells`
checks), and the int64 histogram is saturated straight into the uint8 raster.
"""

import numpy as np
import torch

from lead_s2r.models.config import BEVGrid
from lead_s2r.models.inputs import LIDAR_HITS_MAX


def rasterize_lidar(points: np.ndarray | None, grid: BEVGrid) -> np.ndarray:
    """Point histogram on ``grid`` (H along +x, W along +y), saturated at :data:`LIDAR_HITS_MAX` hits: uint8 (H, W)
    counts, which the backbone scales to LEAD's [0, 1] (:func:`~lead_s2r.models.inputs.lidar_input`)."""
    h, w = grid.shape
    raster = np.zeros((h, w), np.uint8)
    if points is None or not len(points):
        return raster
    counts = np.bincount(_lidar_cells(points, grid), minlength=h * w).reshape(h, w)
    np.minimum(counts, LIDAR_HITS_MAX, out=raster, casting="unsafe")  # <= LIDAR_HITS_MAX: the cast is exact
    return raster


def lidar_xy(points: np.ndarray | None) -> torch.Tensor:
    """The x, y of LiDAR ``points`` (N, >= 2) for :func:`~lead_s2r.data.device_inputs.rasterize_points` on the
    device, as one contiguous copy (a view would send the whole cloud through a loader worker's shared memory)."""
    if points is None:
        return torch.zeros(0, 2)
    return torch.from_numpy(np.ascontiguousarray(points[:, :2]))


def _lidar_cells(points: np.ndarray, grid: BEVGrid) -> np.ndarray:
    """Flat cell index (row * W + column) of each point of ``points`` on ``grid``; points off the grid dropped."""
    h, w = grid.shape
    if points.dtype not in (np.float32, np.float64):  # the index below is exact in these only
        raise TypeError(f"lidar points must be float32 (the schema's 'lidar' field) or float64, got {points.dtype}")
    if h * w > 2**24:
        raise ValueError(f"BEV grid {h}x{w} has more cells than float32 counts exactly (2**24); use a coarser grid")
    rows = points[:, 0] - grid.x_min  # fractional row and column, in place: one temporary each
    rows *= grid.pixels_per_meter
    cols = points[:, 1] - grid.y_min
    cols *= grid.pixels_per_meter
    inside = rows >= 0  # NaN is outside; inside, truncation is the floor
    inside &= rows < h
    inside &= cols >= 0
    inside &= cols < w
    rows, cols = rows[inside], cols[inside]
    cells = np.trunc(rows, out=rows)
    cells *= w
    cells += np.trunc(cols, out=cols)
    return cells.astype(np.intp)
