"""Radar inputs and detection targets of one sample: points padded to a fixed length, and the boxes radar points hit."""

import numpy as np
import torch
from numba import njit

#: Radar points kept per sample (LEAD: 4 sensors x 75).
MAX_RADAR_POINTS = 300
#: Radar detection targets per sample (LEAD: up to 20 objects with at least one radar hit).
MAX_RADAR_TARGETS = 20
#: A radar point counts as a hit on a box up to this far outside its footprint, metres.
RADAR_HIT_MARGIN_M = 0.5


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
    """Radar detection targets: [x, y, speed] of the boxes radar points fall on (inside the footprint grown by
    :data:`RADAR_HIT_MARGIN_M`), fastest first (as LEAD sorts), then by ``priority`` (lower first; LEAD's class order),
    where given. A box of unknown velocity (NaN vx, vy) comes after the known ones with speed NaN, which the loss leaves
    out (:func:`~lead_s2r.models.lead_loss.radar_loss`)."""
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
    """(N boxes,) bool: whether any radar point lies inside the box's footprint grown by :data:`RADAR_HIT_MARGIN_M`.

    The per-box terms (cosine, sine, grown half extents) are numpy's, in the boxes' dtype; the (box, point) pairs are
    tested compiled, a box's scan stopping at its first hit, with :func:`~lead_s2r.geometry.rotate`'s arithmetic in
    the arrays' dtypes operation for operation (numpy's elementwise results, which numba's scalar IEEE arithmetic
    gives bit for bit), so every pair decides as rotate would."""
    yaw = -boxes[:, 6]
    half = boxes[:, 3:5] / 2 + RADAR_HIT_MARGIN_M
    return _any_point_inside(radar[:, 0], radar[:, 1], boxes[:, 0], boxes[:, 1], np.cos(yaw), np.sin(yaw), half)


@njit(cache=True, nogil=True)
def _any_point_inside(
    xs: np.ndarray,
    ys: np.ndarray,
    centre_x: np.ndarray,
    centre_y: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    half: np.ndarray,
) -> np.ndarray:
    """Per box: whether a point (``xs``, ``ys``) lies within ``half`` (N, 2) of its centre in the box's frame."""
    hit = np.zeros(len(centre_x), np.bool_)
    for box in range(len(centre_x)):
        for point in range(len(xs)):
            dx, dy = xs[point] - centre_x[box], ys[point] - centre_y[box]
            if (
                abs(cos[box] * dx - sin[box] * dy) <= half[box, 0]
                and abs(sin[box] * dx + cos[box] * dy) <= half[box, 1]
            ):
                hit[box] = True
                break
    return hit
