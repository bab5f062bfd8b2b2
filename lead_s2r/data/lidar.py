"""LiDAR points -> the BEV hit-count raster the backbone reads, on the loader's CPU (the device does the same with
:func:`~lead_s2r.data.device_inputs.rasterize_points` when the points are left for it).

A LEAD frame has about 60,000 points, so every pass over them and every large temporary shows: the fractional row
and column stay in the points' dtype (float32: a point lands in the cell it always did), the cell index is formed
in that dtype and the in-grid points' indices are picked once (exact below 2**24 cells, which :func:`_lidar_cells`
checks), and the int64 histogram is saturated straight into the uint8 raster.
"""

import numpy as np
import torch

from lead_s2r.models.config import BEVGrid
from lead_s2r.models.inputs import LIDAR_HITS_MAX


def rasterize_lidar(points: np.ndarray | None, grid: BEVGrid, x_shift: float = 0.0) -> np.ndarray:
    """Point histogram on ``grid`` (H along +x, W along +y), saturated at :data:`LIDAR_HITS_MAX` hits: uint8 (H, W)
    counts, which the backbone scales to LEAD's [0, 1] (:func:`~lead_s2r.models.inputs.lidar_input`). Each point's
    x is taken as ``x - x_shift`` in the points' dtype, as :func:`~lead_s2r.data.lead_origin.to_centre_origin`
    moves it (the same numbers, without copying the cloud first)."""
    h, w = grid.shape
    raster = np.zeros((h, w), np.uint8)
    if points is None or not len(points):
        return raster
    counts = np.bincount(_lidar_cells(points, grid, x_shift), minlength=h * w).reshape(h, w)
    np.minimum(counts, LIDAR_HITS_MAX, out=raster, casting="unsafe")  # <= LIDAR_HITS_MAX: the cast is exact
    return raster


def lidar_xy(points: np.ndarray | None, x_shift: float = 0.0) -> torch.Tensor:
    """The x, y of LiDAR ``points`` (N, >= 2) for :func:`~lead_s2r.data.device_inputs.rasterize_points` on the
    device, as one contiguous copy (a view would send the whole cloud through a loader worker's shared memory), x
    moved by ``x_shift`` as :func:`rasterize_lidar` moves it."""
    if points is None:
        return torch.zeros(0, 2)
    xy = _first_two_columns(points)
    if x_shift:
        xy[:, 0] -= xy.dtype.type(x_shift)
    return torch.from_numpy(xy)


#: A word as wide as two values of each dtype, in which a row's x, y are copied as one value.
_PAIR_WORDS = {np.dtype(np.float32): np.dtype(np.uint64), np.dtype(np.float64): np.dtype(np.complex128)}


def _first_two_columns(points: np.ndarray) -> np.ndarray:
    """A contiguous copy of ``points[:, :2]``, byte for byte. numpy copies an (N, 2) slice of wider rows value by
    value (0.29 ms for a LEAD frame's 60,000 points); read as one 8- or 16-byte word per row it is one strided
    copy of N words (0.02 ms)."""
    pair = _PAIR_WORDS.get(points.dtype)
    if pair is None or points.ndim != 2 or points.shape[1] < 2 or points.strides[1] != points.itemsize:
        return points[:, :2].copy()
    words = points[:, :2].view(pair)[:, 0]  # (N,): one word per row, at the row's stride
    return words.copy().view(points.dtype).reshape(len(points), 2)


def _lidar_cells(points: np.ndarray, grid: BEVGrid, x_shift: float) -> np.ndarray:
    """Flat cell index (row * W + column) of each point of ``points`` (x moved by ``x_shift``) on ``grid``; points off
    the grid dropped."""
    h, w = grid.shape
    if points.dtype not in (np.float32, np.float64):  # the index below is exact in these only
        raise TypeError(f"lidar points must be float32 (the schema's 'lidar' field) or float64, got {points.dtype}")
    if h * w > 2**24:
        raise ValueError(f"BEV grid {h}x{w} has more cells than float32 counts exactly (2**24); use a coarser grid")
    if x_shift:  # fractional row and column, in place: one temporary each
        rows = points[:, 0] - points.dtype.type(x_shift)
        rows -= grid.x_min
    else:
        rows = points[:, 0] - grid.x_min
    rows *= grid.pixels_per_meter
    cols = points[:, 1] - grid.y_min
    cols *= grid.pixels_per_meter
    inside = rows >= 0  # NaN is outside; inside, truncation is the floor
    inside &= rows < h
    inside &= cols >= 0
    inside &= cols < w
    with np.errstate(over="ignore", invalid="ignore"):  # far, inf or NaN points: outside, never picked
        cells = np.trunc(rows, out=rows)  # every point's cell, then one pick of the inside ones (not two)
        cells *= w
        cells += np.trunc(cols, out=cols)
    return cells[inside].astype(np.intp)
