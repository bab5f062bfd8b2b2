"""LiDAR points -> the BEV hit-count raster the backbone reads, on the loader's CPU (the device does the same with
:func:`~lead_s2r.data.device_inputs.rasterize_points` when the points are left for it).

A LEAD frame has about 60,000 points: the raster is counted in one compiled pass over them (numba), each point's
fractional row and column formed in the points' dtype (float32: a point lands in the cell it always did) and its
hit added to the uint8 cell unless the cell is saturated, with no temporaries (numpy's passes, a cell index per
point and an int64 histogram took 0.4 ms of a sample's 0.5).
"""

import numpy as np
import torch
from numba import njit

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
    if points.dtype not in (np.float32, np.float64):  # the arithmetic below is the points' own dtype's
        raise TypeError(f"lidar points must be float32 (the schema's 'lidar' field) or float64, got {points.dtype}")
    # the offsets and scale rounded to the points' dtype, as numpy rounds a Python float operand
    offsets = np.array([x_shift, grid.x_min, grid.y_min, grid.pixels_per_meter], points.dtype)
    _count_hits(points, offsets, raster, LIDAR_HITS_MAX)
    return raster


@njit(cache=True, nogil=True)
def _count_hits(points: np.ndarray, offsets: np.ndarray, raster: np.ndarray, saturation: int) -> None:
    """Add each point of ``points`` on the grid to its cell of ``raster`` (uint8, (H, W)), up to ``saturation`` hits.

    Row ``((x - shift) - x_min) * ppm`` and column ``(y - y_min) * ppm`` in the points' dtype (``offsets``: shift,
    x_min, y_min, ppm in it), a point inside when both lie in [0, H) and [0, W) (NaN never does), its cell their
    truncation: numpy's ``(rows - x_min) * ppm`` operation for operation (subtracting a zero shift changes no value)."""
    h, w = raster.shape
    cells = raster.reshape(-1)
    shift, x_min, y_min, ppm = offsets[0], offsets[1], offsets[2], offsets[3]
    for i in range(points.shape[0]):
        row = ((points[i, 0] - shift) - x_min) * ppm
        col = (points[i, 1] - y_min) * ppm
        if row >= 0 and row < h and col >= 0 and col < w:
            cell = int(row) * w + int(col)
            count = cells[cell]
            cells[cell] = count + (count < saturation)  # no branch on the count: a saturated cell stays


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
    """A contiguous copy of ``points[:, :2]``, byte for byte: numpy copies an (N, 2) slice of wider rows value by value
    (0.29 ms for a LEAD frame's 60,000 points); read as one 8- or 16-byte word per row, one strided copy (0.02 ms)."""
    pair = _PAIR_WORDS.get(points.dtype)
    if pair is None or points.ndim != 2 or points.shape[1] < 2 or points.strides[1] != points.itemsize:
        return points[:, :2].copy()
    words = points[:, :2].view(pair)[:, 0]  # (N,): one word per row, at the row's stride
    return words.copy().view(points.dtype).reshape(len(points), 2)
