"""What ``lead-s2r serve alpasim`` serves: a run of ours or a LEAD checkpoint folder, checked to be drivable from
AlpaSim's sensors (cameras, egomotion and a route: no LiDAR, no radar), with the camera layout it was trained on.

The layout is a list of camera directions and fields of view, never names: the cameras a run read for its source
(``data.*.cameras`` in its ``config.yaml``), a LEAD folder's ``used_cameras`` of its target, or a CARLA model's LEAD
rig (:func:`~lead_s2r.closed_loop.checkpoint.rig_for`), each at its nominal direction (:data:`CAMERA_DIRECTIONS`).
"""

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from torch import nn

from lead_s2r.closed_loop.checkpoint import (
    LEAD_CONFIG_NAME,
    UnsupportedCheckpoint,
    family_spec,
    load_driving_model,
    rig_for,
    saved_config,
)
from lead_s2r.data.collate import collate
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.errors import UserError
from lead_s2r.formats.carla_rig import CAMERA_RIGS
from lead_s2r.models.input_spec import InputSpec
from lead_s2r.models.lead_config import LeadConfig, TargetDataset

#: Direction (degrees, counter-clockwise from forward) and horizontal field of view of the cameras of our schema
#: (nuPlan's rig, which NAVSIM's and WOD-E2E's ids follow).
CAMERA_DIRECTIONS: dict[str, tuple[float, float]] = {
    "front": (0.0, 63.71),
    "front_left": (55.0, 63.71),
    "left": (90.0, 63.71),
    "back_left": (135.0, 63.71),
    "back": (180.0, 63.71),
    "back_right": (-135.0, 63.71),
    "right": (-90.0, 63.71),
    "front_right": (-55.0, 63.71),
}
#: LEAD's cameras of a target, in its ``used_cameras`` order (a LEAD folder names no data cameras).
LEAD_CAMERAS = {
    TargetDataset.NAVSIM_4CAMERAS: ("front_left", "front", "front_right", "back"),
    TargetDataset.WAYMO_E2E_2025_3CAMERAS: ("front_left", "front", "front_right"),
}


@dataclass(frozen=True)
class CameraSlot:
    """One camera the model reads: its sample field id, direction (degrees, ISO) and horizontal field of view."""

    id: str
    yaw_deg: float
    fov_deg: float


@dataclass
class ServedModel:
    """The network, what it reads and how its camera layout looks, shared by every session (read only)."""

    model: nn.Module
    source: str
    spec: InputSpec
    slots: tuple[CameraSlot, ...]
    device: torch.device
    path: Path
    transform: SourceTransform = field(init=False)

    def __post_init__(self) -> None:
        self.transform = SourceTransform(self.source, self.spec, cameras=[slot.id for slot in self.slots])

    @property
    def grid_times(self) -> np.ndarray:
        return np.asarray(self.spec.trajectory_grids[self.source].times, np.float64)

    @torch.inference_mode()
    def plan(self, sample: dict[str, Any]) -> np.ndarray:
        """(T, 3) x, y, yaw on the output grid, in the rig frame, for one sample (the ``predict`` path)."""
        batch = collate([self.transform(sample)])
        inputs = {k: v.to(self.device) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}
        out = self.model(inputs, self.source, {"waypoints", "headings"})
        waypoints = out["waypoints"][0].float().cpu().numpy().astype(np.float64)
        if "headings" in out:
            yaw = out["headings"][0].float().cpu().numpy().astype(np.float64)
        else:  # the direction of travel along the waypoints, starting from the origin
            steps = np.diff(np.vstack([np.zeros((1, 2)), waypoints]), axis=0)
            yaw = np.arctan2(steps[:, 1], steps[:, 0])
        return np.column_stack([waypoints, yaw])


def load_served_model(path: str | Path, source: str | None, pattern: str, device: str) -> ServedModel:
    """A run (folder or checkpoint) or a LEAD checkpoint folder, checked to be drivable from AlpaSim's sensors."""
    try:
        model, found = load_driving_model(path, pattern, device)
        spec = family_spec(model, found, "from AlpaSim's cameras")
    except (UnsupportedCheckpoint, FileNotFoundError) as err:
        raise UserError(f"serve alpasim: {err}") from None
    if spec.lidar_raster or spec.radar:
        sensor = "LiDAR" if spec.lidar_raster else "radar"
        raise UserError(f"{found}: the model reads {sensor}, which AlpaSim's driver contract does not provide; serve "
                        "a camera-only model (LTFv6, use_radar false)")  # fmt: skip
    sources = [s for s in spec.trajectory_grids if "waypoints" in model.tasks(s)]
    if source is None:
        source = "navsim" if "navsim" in sources else (sources or [""])[0]
    if source not in sources:
        raise UserError(f"{found}: --source {source!r}: the model plans for {sources}; pick one of them")
    slots = camera_slots(model.config, spec, source, found)
    return ServedModel(model, source, spec, slots, torch.device(device), found)


def camera_slots(config: Any, spec: InputSpec, source: str, found: Path) -> tuple[CameraSlot, ...]:
    """The model's cameras left to right, at their nominal directions (the module docstring says whose)."""
    if source == "carla":
        return tuple(CameraSlot(c.name, -c.yaw_deg, c.fov_deg) for c in CAMERA_RIGS[rig_for(spec)])
    ids = run_cameras(found, source) if not (found / LEAD_CONFIG_NAME).is_file() else None
    if ids is None and isinstance(config, LeadConfig) and config.target_dataset in LEAD_CAMERAS:
        ids = [c for c, used in zip(LEAD_CAMERAS[config.target_dataset], config.used_cameras, strict=True) if used]
    if not ids:
        raise UserError(f"{found}: no camera list for source {source!r} (data.predict/train.{source}.cameras in the "
                        f"run's config.yaml); pass the run folder of `lead-s2r fit`")  # fmt: skip
    if not set(ids) <= set(CAMERA_DIRECTIONS):
        raise UserError(f"{found}: cameras {ids} of source {source!r}: only {sorted(CAMERA_DIRECTIONS)} have a "
                        "direction to match AlpaSim's cameras by")  # fmt: skip
    return tuple(CameraSlot(c, *CAMERA_DIRECTIONS[c]) for c in ids)


def run_cameras(checkpoint: Path, source: str) -> list[str] | None:
    """The camera fields a run read for ``source`` (``data.predict``, else ``data.train``), None where unknown."""
    try:
        config = yaml.safe_load(saved_config(checkpoint).read_text()) or {}
    except UnsupportedCheckpoint:
        return None
    data = config.get("data") or {}
    for stage in ("predict", "train", "val"):
        cameras = ((data.get(stage) or {}).get(source) or {}).get("cameras")
        if cameras:
            return list(cameras)
    return None
