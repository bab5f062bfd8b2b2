"""Radar inputs and radar detection targets of one sample: points padded to a fixed length, and the boxes radar
points fall on (LEAD's radar detector's labels)."""

import numpy as np
import torch

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
    """Radar detection targets: [x, y, speed] of the boxes radar points fall on, fastest first (as LEAD sorts), then
    by ``priority`` (lower first; LEAD's class order), where given. A box of unknown velocity (NaN vx, vy) comes
    after the known ones with speed NaN, which the loss leaves out (:func:`~lead_s2r.models.lead_loss.radar_loss`).

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
