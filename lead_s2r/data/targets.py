"""Training targets of one sample on the model's grids: radar points and radar detection targets, BEV class maps,
CenterNet box heatmaps and regression targets (LEAD's route target: :mod:`lead_s2r.data.lead_route`).

Pure functions of one decoded sample and the grid; whatever depends only on the configuration is computed once per
process and cached (the BEV label gather index, the CenterNet Gaussian windows). Each output is bit-identical to the
straightforward definition kept in tests/test_transform_speed.py.
"""

import math
from functools import lru_cache
from typing import Any

import numpy as np
import torch

from lead_s2r.geometry import raster_lookup
from lead_s2r.models.config import BEVGrid
from lead_s2r.models.inputs import IGNORE_CLASS
from lead_s2r.schema import BoxClass

#: Radar points kept per sample (LEAD: 4 sensors x 75).
MAX_RADAR_POINTS = 300
#: Boxes kept per sample for the CenterNet regression targets.
MAX_BOXES = 64
#: Radar detection targets per sample (LEAD: up to 20 objects with at least one radar hit).
MAX_RADAR_TARGETS = 20
#: A radar point counts as a hit on a box up to this far outside its footprint, metres.
RADAR_HIT_MARGIN_M = 0.5
CENTERNET_STRIDE = 4


def bev_cell_centres(grid: BEVGrid, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Ego x (rows) and y (columns) of the cell centres of ``grid`` at ``stride``."""
    h, w = grid.shape
    cell = stride / grid.pixels_per_meter
    xs = grid.x_min + (np.arange(h // stride) + 0.5) * cell
    ys = grid.y_min + (np.arange(w // stride) + 0.5) * cell
    return xs, ys


def pad_points(name: str, points: np.ndarray | None, size: int, columns: int) -> dict[str, torch.Tensor]:
    """First ``size`` rows of ``points`` zero-padded to a fixed length, with a validity mask."""
    padded = np.zeros((size, columns), np.float32)
    valid = np.zeros(size, bool)
    if points is not None:
        n = min(len(points), size)
        padded[:n] = points[:n, :columns]
        valid[:n] = True
    return {name: torch.from_numpy(padded), f"{name}_valid": torch.from_numpy(valid)}


def radar_targets(radar: np.ndarray, boxes: np.ndarray, priority: np.ndarray | None = None) -> dict[str, torch.Tensor]:
    """Radar detection targets: [x, y, speed] of the boxes radar points fall on, fastest first (as LEAD sorts), then
    by ``priority`` (lower first; LEAD's class order), where given.

    A point hits a box when it lies inside the box's footprint grown by :data:`RADAR_HIT_MARGIN_M`.
    """
    targets = np.zeros((MAX_RADAR_TARGETS, 3), np.float32)
    valid = np.zeros(MAX_RADAR_TARGETS, bool)
    if len(radar) and len(boxes):
        hit = _radar_hits(radar, boxes)
        speed = np.hypot(boxes[:, 7], boxes[:, 8])
        rank = np.zeros(len(boxes)) if priority is None else np.asarray(priority)
        chosen = np.flatnonzero(hit)[np.lexsort((rank[hit], -speed[hit]))][:MAX_RADAR_TARGETS]
        targets[: len(chosen)] = np.stack([boxes[chosen, 0], boxes[chosen, 1], speed[chosen]], axis=1)
        valid[: len(chosen)] = True
    return {"radar_targets": torch.from_numpy(targets), "radar_targets_valid": torch.from_numpy(valid)}


def _radar_hits(radar: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(N boxes,) bool: whether any radar point lies inside the box's footprint grown by
    :data:`RADAR_HIT_MARGIN_M`.

    Every (box, point) pair is tested on (boxes, points) planes, x and y apart (docs/benchmarks.md, "Training
    targets"); the arithmetic is :func:`~lead_s2r.geometry.rotate`'s, element for element, so every pair decides as
    rotate would.
    """
    dx = radar[None, :, 0] - boxes[:, 0, None]
    dy = radar[None, :, 1] - boxes[:, 1, None]
    yaw = -boxes[:, 6, None]
    cos, sin = np.cos(yaw), np.sin(yaw)
    half = boxes[:, 3:5] / 2 + RADAR_HIT_MARGIN_M
    inside = np.abs(cos * dx - sin * dy) <= half[:, 0, None]
    inside &= np.abs(sin * dx + cos * dy) <= half[:, 1, None]
    return inside.any(axis=1)


def nan_to_zero(values: np.ndarray) -> np.ndarray:
    """float64 ``values`` (resampled, NaN where masked) as float32 with NaN as 0.

    Equal to ``np.nan_to_num(values).astype(np.float32)`` (whose +-float64 max for +-inf round to +-inf in float32)
    in three numpy calls instead of a dozen: this runs three times per sample on arrays of a few dozen numbers."""
    out = values.astype(np.float32)
    out[np.isnan(out)] = 0.0
    return out


def bev_labels(labels: np.ndarray, spec: dict[str, Any], grid: BEVGrid) -> np.ndarray:
    """Class ids (uint8) of a stored BEV raster (``meta.bev`` spec) at ``grid``'s cell centres; :data:`IGNORE_CLASS`
    outside it.

    The nearest-pixel lookup depends only on the spec, the raster's shape and the grid, so it is computed once
    (:func:`bev_gather_index`) and each sample is one gather."""
    pixel_to_ego = tuple(tuple(float(v) for v in row) for row in spec["pixel_to_ego"])
    index = bev_gather_index(pixel_to_ego, labels.shape[:2], grid)
    values = np.empty(labels.shape[0] * labels.shape[1] + 1, np.uint8)
    values[:-1] = labels.reshape(-1)
    values[-1] = IGNORE_CLASS  # where the index points for cells outside the raster
    return values[index]


@lru_cache(maxsize=64)
def bev_gather_index(pixel_to_ego: tuple[tuple[float, ...], ...], shape: tuple[int, int], grid: BEVGrid) -> np.ndarray:
    """(H, W) flat index into a raster of ``shape`` of every grid cell; ``shape[0] * shape[1]`` (one past the end)
    outside it. :func:`~lead_s2r.geometry.raster_lookup` of a raster of flat indices, so both agree by construction."""
    xs, ys = bev_cell_centres(grid)
    x, y = np.meshgrid(xs, ys, indexing="ij")
    size = shape[0] * shape[1]
    index = raster_lookup(np.arange(size).reshape(shape), np.asarray(pixel_to_ego), x, y, fill=size)
    index.flags.writeable = False  # shared by every sample
    return index


def centernet_targets(boxes: np.ndarray, grid: BEVGrid, num_classes: int) -> dict[str, torch.Tensor]:
    """CenterNet targets on ``grid`` at stride 4: Gaussian heatmaps per class and per-box regression targets.

    With a single class only vehicles are kept (NAVSIM's agent head); otherwise the class is the unified
    :class:`~lead_s2r.schema.BoxClass` id. The first :data:`MAX_BOXES` boxes whose centre falls on the grid count.
    Each Gaussian is drawn only where it is non-zero in float32 (:func:`gaussian_window`), which gives the same
    heatmap as drawing it over the whole grid.
    """
    h, w = grid.shape[0] // CENTERNET_STRIDE, grid.shape[1] // CENTERNET_STRIDE
    cell = CENTERNET_STRIDE / grid.pixels_per_meter
    boxes = np.asarray(boxes, np.float32).reshape(-1, 10)
    labels = boxes[:, 9].astype(np.int64)
    if num_classes == 1:
        keep, labels = labels == BoxClass.VEHICLE, np.zeros_like(labels)
    else:
        keep = labels < num_classes
    row_f, col_f = (boxes[:, 0] - grid.x_min) / cell, (boxes[:, 1] - grid.y_min) / cell
    rows, cols = np.floor(row_f).astype(np.int64), np.floor(col_f).astype(np.int64)
    keep &= (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    chosen = np.flatnonzero(keep)[:MAX_BOXES]
    picked, rows, cols = boxes[chosen], rows[chosen], cols[chosen]
    sigma = np.maximum(np.float32(0.5), np.minimum(picked[:, 3], picked[:, 4]) / cell / 6.0)
    heatmap = np.zeros((num_classes, h, w), np.float32)
    draws = zip(labels[chosen].tolist(), rows.tolist(), cols.tolist(), (2 * sigma**2).tolist(), strict=True)
    for label, row, col, denominator in draws:  # Python numbers: a numpy scalar per box costs more than the draw
        _draw_gaussian(heatmap[label], row, col, denominator)
    offset = np.stack([row_f[chosen] - rows.astype(np.float32), col_f[chosen] - cols.astype(np.float32)], axis=1)
    speed = np.hypot(picked[:, 7].astype(np.float64), picked[:, 8].astype(np.float64))
    regression = {
        "box_index": _first_rows(rows * w + cols, np.int64),
        "box_valid": np.arange(MAX_BOXES) < len(chosen),
        "box_offset": _first_rows(offset, np.float32),
        "box_size": _first_rows(picked[:, 3:5], np.float32),
        "box_yaw": _first_rows(picked[:, 6], np.float32),
        "box_velocity": _first_rows(speed, np.float32),
    }
    return {"box_heatmap": torch.from_numpy(heatmap), **{k: torch.from_numpy(v) for k, v in regression.items()}}


def _first_rows(values: np.ndarray, dtype: type) -> np.ndarray:
    """``values`` (at most :data:`MAX_BOXES` rows) cast to ``dtype`` and zero-padded to :data:`MAX_BOXES` rows."""
    out = np.zeros((MAX_BOXES, *values.shape[1:]), dtype)
    out[: len(values)] = values
    return out


#: exp(-q) rounds to 0 in float32 beyond this q (below half the smallest subnormal, 2**-150: ln 2**-150 = -103.97).
_FLOAT32_EXP_ZERO = 104.0


def _draw_gaussian(heatmap: np.ndarray, row: int, col: int, denominator: float) -> None:
    """``heatmap = max(heatmap, exp(-d^2 / denominator))`` (d: cell distance from (row, col)), in float64 rounded to
    float32, over the window outside which every value is 0 in float32 (:func:`gaussian_window`)."""
    paste_max(heatmap, row, col, gaussian_window(denominator)[1])


def paste_max(heatmap: np.ndarray, row: int, col: int, window: np.ndarray) -> None:
    """``heatmap = max(heatmap, window)`` with the (2r+1)^2 ``window`` centred on (row, col), cut at the heatmap's
    edges."""
    radius = window.shape[0] // 2
    r0, r1 = max(row - radius, 0), min(row + radius + 1, heatmap.shape[0])
    c0, c1 = max(col - radius, 0), min(col + radius + 1, heatmap.shape[1])
    target = heatmap[r0:r1, c0:c1]
    np.maximum(target, window[r0 - row + radius : r1 - row + radius, c0 - col + radius : c1 - col + radius], out=target)


@lru_cache(maxsize=256)
def gaussian_window(denominator: float) -> tuple[int, np.ndarray]:
    """(radius, the (2 radius + 1)^2 float32 window ``exp(-d^2 / denominator)`` around its centre cell), zero in
    float32 beyond ``radius``.

    Cached per denominator: most boxes sit at the 0.5-cell sigma floor (cars, pedestrians), and a dataset's vehicle
    models repeat their sizes, so a few windows serve nearly every box; each value is the same float64 ``exp`` of
    the same integer ``d^2`` whichever box it serves, rounded to float32."""
    radius = math.isqrt(int(_FLOAT32_EXP_ZERO * denominator)) + 1
    offsets = np.arange(-radius, radius + 1)
    window = np.exp(-(offsets[:, None] ** 2 + offsets[None, :] ** 2) / denominator).astype(np.float32)
    window.flags.writeable = False  # shared by every box with this denominator
    return radius, window
