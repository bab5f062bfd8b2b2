"""LEAD's CenterNet box targets on our BEV grid (``get_centernet_labels`` of LEAD's CARLA and NAVSIM loaders, 4489176).

LEAD's encoding, on the CenterNet grid at a quarter of the BEV resolution (1 cell per metre at LEAD's 4 px/m): a
Gaussian peak per box at its centre's cell (CornerNet's radius for a minimum IoU of 0.1 of the half extents in
cells, at least 2; sigma = diameter / 6), and at that cell the half length and half width in cells, the centre's
sub-cell offset, the yaw as one of 12 bins and its residual from the bin centre (LEAD's ``angle2class``), the speed,
and a weight of 1; a later box in the same cell overwrites the earlier one's values. The per-sample normaliser is
the number of heatmap cells equal to 1 (at least 1).

Values are in our frame (lateral offset along +y left, yaw counter-clockwise); :mod:`lead_s2r.models.lead_frame`
turns LEAD's predictions into the same frame, so the loss equals LEAD's.

LEAD pads its box list to 90 rows with zeros and encodes the padding too (both its CARLA and NAVSIM loaders): a phantom
box of class 0 and size 0 in the corner cell of its map at (min x, min y right), i.e. our row 0 and last column, with a
radius-2 peak that counts in the normaliser and a weight of 1 there. LEAD's released networks were trained with it, so
we encode it as LEAD does, as one more box after the real ones; tests/test_lead_data_parity.py pins it.
"""

import math
from functools import lru_cache

import numpy as np
import torch
from numba import njit

from lead_s2r.models.config import BEVGrid

#: BEV pixels per CenterNet cell (LEAD's ``bev_down_sample_factor``).
CENTERNET_STRIDE = 4
#: LEAD's ``max_num_bbs``: boxes encoded per sample, in list order.
LEAD_MAX_BOXES = 90
#: CornerNet's minimum IoU and LEAD's smallest radius, in cells.
MIN_OVERLAP, MIN_RADIUS = 0.1, 2


def gaussian_radius(height: float, width: float, min_overlap: float = MIN_OVERLAP) -> float:
    """CornerNet's Gaussian radius: the smallest of the three corner-displacement cases' largest radius that keeps
    an IoU of ``min_overlap`` with a ``height`` x ``width`` box (LEAD's ``gaussian_radius``, after mmdetection)."""
    b1, c1 = height + width, width * height * (1 - min_overlap) / (1 + min_overlap)
    r1 = (b1 - math.sqrt(b1**2 - 4 * c1)) / 2
    b2, c2 = 2 * (height + width), (1 - min_overlap) * width * height
    r2 = (b2 - math.sqrt(b2**2 - 16 * c2)) / 8
    a3, b3, c3 = 4 * min_overlap, -2 * min_overlap * (height + width), (min_overlap - 1) * width * height
    r3 = (b3 + math.sqrt(b3**2 - 4 * a3 * c3)) / (2 * a3)
    return min(r1, r2, r3)


@lru_cache(maxsize=4096)
def kernel_radius(half_width: float, half_length: float) -> int:
    """LEAD's integer Gaussian radius of a box, in cells. Per box in Python floats, as LEAD computes it (numpy's
    square is not ``pow``'s in the last bit, and an integer radius can hang on it); cached, as a recording's actors
    keep their sizes from frame to frame."""
    return max(MIN_RADIUS, int(gaussian_radius(half_width, half_length)))


@lru_cache(maxsize=64)
def gaussian_kernel(radius: int) -> np.ndarray:
    """(2r+1)^2 float32 ``exp(-d^2 / (2 sigma^2))`` with sigma = (2r+1) / 6, values below float32 eps x max zeroed."""
    offsets = np.arange(-radius, radius + 1, dtype=np.float32)
    sigma = (2 * radius + 1) / 6
    kernel = np.exp(-(offsets[None, :] ** 2 + offsets[:, None] ** 2) / np.float32(2 * sigma * sigma))
    kernel[kernel < np.finfo(np.float32).eps * kernel.max()] = 0
    kernel.flags.writeable = False
    return kernel


def angle_bin(angles: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """(bin, residual) of each of ``angles``: bin k is centred on k * 2 pi / bins (LEAD's ``angle2class``). numpy's
    ``%`` and ``//`` on floats are Python's (fmod, then the divisor's sign), so the values are LEAD's bit for bit."""
    width = 2 * math.pi / bins
    shifted = (np.asarray(angles, np.float64) % (2 * math.pi) + width / 2) % (2 * math.pi)
    k = shifted // width
    return k.astype(np.int64), shifted - (k * width + width / 2)


def lead_centernet_targets(
    boxes: np.ndarray, classes: np.ndarray, grid: BEVGrid, num_classes: int, yaw_bins: int, velocity: bool = True
) -> dict[str, torch.Tensor]:
    """LEAD's CenterNet targets of (N, 10) boxes on ``grid``'s stride-4 cells: ``lead_box_heatmap`` (C, h, w),
    ``lead_box_size`` and ``lead_box_offset`` (2, h, w), ``lead_box_yaw_class`` (h, w) uint8,
    ``lead_box_yaw_residual``, ``lead_box_velocity`` (h, w), ``lead_box_weight`` (h, w) bool and
    ``lead_box_count``. ``classes`` holds each box's heatmap channel (-1: not encoded); centres off the grid are
    skipped, as LEAD's BEV bounds filter; fewer than :data:`LEAD_MAX_BOXES` add LEAD's padding box. Without
    ``velocity`` (NAVSIM: LEAD trains no speed there) the speed map is left out; a box of unknown velocity (NaN vx,
    vy) leaves NaN in its cell, which the loss skips (:func:`~lead_s2r.training.losses.lead_box_loss`)."""
    h, w = grid.shape[0] // CENTERNET_STRIDE, grid.shape[1] // CENTERNET_STRIDE
    cell = CENTERNET_STRIDE / grid.pixels_per_meter
    heatmap = np.zeros((num_classes, h, w), np.float32)
    size, offset = np.zeros((2, h, w), np.float32), np.zeros((2, h, w), np.float32)
    yaw_class, weight = np.zeros((h, w), np.uint8), np.zeros((h, w), bool)
    yaw_residual, speed = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    boxes = np.asarray(boxes, np.float64).reshape(-1, 10)
    row_f, col_f = (boxes[:, 0] - grid.x_min) / cell, (boxes[:, 1] - grid.y_min) / cell
    on_grid = (row_f >= 0) & (row_f < h) & (col_f > 0) & (col_f <= w)
    kept = np.flatnonzero((np.asarray(classes) >= 0) & on_grid)[:LEAD_MAX_BOXES]  # LEAD filters, then keeps 90
    picked, row_f, col_f = boxes[kept], row_f[kept], col_f[kept]
    half_length, half_width = picked[:, 3] / 2 / cell, picked[:, 4] / 2 / cell
    # LEAD truncates its y right: a centre on a cell edge is in the cell to our right, offset 1 (LEAD's 0)
    rows, cols = np.floor(row_f).astype(np.int64), np.ceil(col_f).astype(np.int64) - 1
    extents = zip(half_width.tolist(), half_length.tolist(), strict=True)
    radii = np.array([kernel_radius(width, length) for width, length in extents], np.int64)
    labels = np.asarray(classes, np.int64)[kept]
    yaw_bin, yaw_rest = angle_bin(picked[:, 6], yaw_bins)
    speeds = np.hypot(picked[:, 7], picked[:, 8])
    values = np.stack([half_length, half_width, row_f - rows, col_f - cols, yaw_rest, speeds]).reshape(6, -1)
    if len(kept) < LEAD_MAX_BOXES:
        # LEAD's padding box, after the real ones as LEAD's loop writes it: class 0, size, yaw and speed 0, at LEAD's
        # cell (0, 0) with sub-cell offset (0, 0); in our frame row 0, last column, and lateral offset 1
        labels, rows, cols, yaw_bin = np.r_[labels, 0], np.r_[rows, 0], np.r_[cols, w - 1], np.r_[yaw_bin, 0]
        radii = np.r_[radii, kernel_radius(0.0, 0.0)]
        values = np.c_[values, [0.0, 0.0, 0.0, 1.0, 0.0, 0.0]]
    bank, starts = kernel_bank(int(radii.max(initial=0)))
    maps = (heatmap, size, offset, yaw_class, yaw_residual, speed, weight)
    _encode_boxes(maps, labels, rows, cols, radii, bank, starts, values, yaw_bin)
    out = {f"lead_box_{name}": torch.from_numpy(m) for name, m in zip(MAP_NAMES, maps, strict=True)}
    if not velocity:
        del out["lead_box_velocity"]
    out["lead_box_count"] = torch.scalar_tensor(np.float32(max(1, np.count_nonzero(heatmap == 1))))
    return out


#: The target maps :func:`lead_centernet_targets` writes, by their batch keys without ``lead_box_``.
MAP_NAMES = ("heatmap", "size", "offset", "yaw_class", "yaw_residual", "velocity", "weight")
Maps = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@lru_cache(maxsize=8)
def kernel_bank(radius: int) -> tuple[np.ndarray, np.ndarray]:
    """Every :func:`gaussian_kernel` of radius 0 to at least ``radius`` (a power of two, at least 8), flattened one
    after another, and the index where each radius's starts: the kernels :func:`_encode_boxes` reads."""
    largest = max(8, 1 << (radius - 1).bit_length())
    kernels = [gaussian_kernel(r).reshape(-1) for r in range(largest + 1)]
    bank, starts = np.concatenate(kernels), np.cumsum([0] + [len(kernel) for kernel in kernels[:-1]])
    bank.flags.writeable = starts.flags.writeable = False
    return bank, starts


@njit(cache=True, nogil=True)
def _encode_boxes(
    maps: Maps,
    labels: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    radii: np.ndarray,
    bank: np.ndarray,
    starts: np.ndarray,
    values: np.ndarray,
    yaw_bin: np.ndarray,
) -> None:
    """LEAD's per-box loop into ``maps``, compiled: each box's Gaussian (the elementwise maximum with the kernel of
    its radius, from :func:`kernel_bank`, cut at the map's edges) on channel ``labels`` at (``rows``, ``cols``), then
    its cell's values (``values``: half length, half width, row and column offsets, yaw residual and speed, float64,
    each cast to float32 on writing as numpy casts it; ``yaw_bin``), a later box in a cell overwriting an earlier
    one's, as LEAD's loop does."""
    heatmap, size, offset, yaw_class, yaw_residual, speed, weight = maps
    _, h, w = heatmap.shape
    for box in range(len(rows)):
        radius, label, row, col = radii[box], labels[box], rows[box], cols[box]
        side, start = 2 * radius + 1, starts[radius]
        for i in range(max(0, radius - row), min(side, h - row + radius)):
            for j in range(max(0, radius - col), min(side, w - col + radius)):
                value = bank[start + i * side + j]
                if value > heatmap[label, row + i - radius, col + j - radius]:
                    heatmap[label, row + i - radius, col + j - radius] = value
        size[0, row, col], size[1, row, col] = values[0, box], values[1, box]
        offset[0, row, col], offset[1, row, col] = values[2, box], values[3, box]
        yaw_class[row, col], yaw_residual[row, col], speed[row, col] = yaw_bin[box], values[4, box], values[5, box]
        weight[row, col] = True
