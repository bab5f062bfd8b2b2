"""What a NAVSIM sample is made of whether its scene is logged (:mod:`lead_s2r_adapters.navsim_log`) or synthetic
(:mod:`lead_s2r_adapters.navsim_synthetic`): the ego status, the shared ``meta``, the future tracks of the other
agents, the logged ego past and the map fields. Both builders hand over plain arrays; one implementation each.
"""

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import shapely

from lead_s2r.errors import UserError
from lead_s2r.geometry import rotate, to_local, wrap_angle
from lead_s2r.registry import LogRef
from lead_s2r.schema import SCHEMA_VERSION, Command
from lead_s2r_adapters import navsim_map
from lead_s2r_adapters.navsim_filter import SceneFilter

#: ``driving_command`` one-hot order (left, forward, right, unknown).
COMMANDS = (Command.LEFT, Command.STRAIGHT, Command.RIGHT, Command.UNKNOWN)
#: nuPlan's Chrysler Pacifica (``get_pacifica_parameters``).
PACIFICA = {"length": 5.176, "width": 2.297, "wheel_base": 3.089, "rear_axle_to_center": 1.461}


class SceneSource(Protocol):
    """What the scene builders read of the adapter (:class:`~lead_s2r_adapters.navsim.NavsimAdapter`)."""

    name: str
    version: str
    history: int
    future: int
    maps: Path | None
    map_radius: float
    filter: SceneFilter | None

    def two_stage_extras(self, token: str) -> dict[str, Any]: ...

    def tags(self, token: str) -> list[str]: ...


def ego_meta(velocity: list[float], acceleration: list[float], one_hot: np.ndarray, previous: np.ndarray) -> dict:
    """``meta.ego`` from a NAVSIM ego status; the yaw rate comes from the previous past pose ``[t < 0, x, y, yaw]``
    (the status has none), 0 without one. A command that is not one-hot is UNKNOWN's raw code 3."""
    raw = int(np.argmax(one_hot)) if one_hot.sum() == 1 else 3
    yaw_rate = float(wrap_angle(0.0 - previous[3]) / (0.0 - previous[0])) if previous[0] < 0 else 0.0
    return {
        "speed": math.hypot(*velocity),
        "velocity": list(velocity),
        "acceleration": list(acceleration),
        "yaw_rate": yaw_rate,
        "command": int(COMMANDS[raw]),
        "command_raw": raw,
    }


@dataclass(frozen=True)
class SceneFrame:
    """Where a sample sits: its log, the current frame's index and timestamp, and whether the scene is synthetic."""

    log: LogRef
    log_id: str
    frame_idx: int
    timestamp_us: int
    is_synthetic: bool


def scene_meta(
    source: SceneSource,
    frame: SceneFrame,
    extras: dict[str, Any],
    ego: dict[str, Any],
    cameras: list[dict[str, Any]],
    sample: dict[str, Any],
) -> dict[str, Any]:
    """The ``meta`` of a NAVSIM sample, logged or synthetic; ``sample`` holds every other field already."""
    meta = {
        "schema_version": SCHEMA_VERSION,
        "dataset": "navsim",
        "split": source.filter.name if source.filter else frame.log.split,
        "log_id": frame.log_id,
        "frame_idx": frame.frame_idx,
        "timestamp_us": frame.timestamp_us,
        "is_synthetic": frame.is_synthetic,
        "location": extras["map_name"],
        "adapter": source.name,
        "adapter_version": source.version,
        "vehicle": dict(PACIFICA),
        "extras": {"navsim": extras},
        "ego": ego,
        "cameras": cameras,
        "has": {name: True for name in sample if name not in ("__key__", "meta")},
        "tags": source.tags(extras["scene_token"]),
    }
    if "bev_semantic" in sample:
        meta["bev"] = navsim_map.BEV_META
    return meta


@dataclass(frozen=True)
class TrackStep:
    """The boxes of one future keyframe: track tokens, poses (N, 3) [x, y, yaw], velocities (N, 2), sizes (N, 3) and
    :class:`~lead_s2r.schema.BoxClass` ids. Poses are global and velocities in a frame rotated by ``velocity_yaw``
    from the global one when :func:`agents_future` gets an ``origin``, else both are in the current ego frame."""

    tracks: list[str]
    poses: np.ndarray
    velocity: np.ndarray
    velocity_yaw: float
    size: np.ndarray
    classes: np.ndarray


def agents_future(
    now_tracks: list[str],
    now_size: np.ndarray,
    now_classes: np.ndarray,
    steps: list[TrackStep],
    t: np.ndarray,
    origin: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """Future poses of every track seen after the current frame, in the current ego frame (global pose ``origin``;
    None: the steps are in it already): the current boxes' tracks first (row i = box i), then tracks that appear
    later; NaN and ``valid`` False where a track is unseen. ``t`` (seconds after the current frame) has one entry per
    step. One layout for NAVSIM's logs and scenes and 123D's logs (docs/datasets/navsim.md)."""
    horizon = len(steps)
    order = {token: i for i, token in enumerate(now_tracks)}
    size = dict(zip(now_tracks, np.asarray(now_size).reshape(-1, 3), strict=True))
    classes = {token: int(label) for token, label in zip(now_tracks, now_classes, strict=True)}
    rows = []
    for step in steps:
        for i, token in enumerate(step.tracks):
            if token not in order:
                order[token] = len(order)
                size[token], classes[token] = step.size[i], int(step.classes[i])
            rows.append(order[token])
    # every future box of every step in one frame change: the step of each box, its pose and its velocity
    index = np.repeat(np.arange(horizon), [len(step.tracks) for step in steps])
    poses = np.concatenate([step.poses.reshape(-1, 3) for step in steps] or [np.zeros((0, 3))])
    velocity = np.concatenate([step.velocity.reshape(-1, 2) for step in steps] or [np.zeros((0, 2))])
    if origin is not None:
        poses = to_local(poses, origin)
        velocity = rotate(velocity, np.array([step.velocity_yaw for step in steps])[index] - origin[2])
    count = len(order)
    out_poses = np.full((count, horizon, 3), np.nan, np.float32)
    out_velocity = np.full((count, horizon, 2), np.nan, np.float32)
    valid = np.zeros((count, horizon), bool)
    rows = np.array(rows, np.int64)
    out_poses[rows, index], out_velocity[rows, index], valid[rows, index] = poses, velocity, True
    ordered = sorted(order, key=order.get)
    return {
        "t": np.asarray(t, np.float32),
        "poses": out_poses,
        "velocity": out_velocity,
        "valid": valid,
        "size": np.array([size[token] for token in ordered], np.float32).reshape(count, 3),
        "class": np.array([classes[token] for token in ordered], np.int8),
        "num_boxes": np.array(len(now_tracks), np.int64),
    }


def ego_past(
    stamps: np.ndarray, poses: np.ndarray, dynamics: np.ndarray, origin: np.ndarray, now_us: int
) -> np.ndarray:
    """(P, 8) float64 of the history frames: t (s), x, y, heading in the current ego frame (global pose ``origin``,
    timestamp ``now_us``), then vx, vy, ax, ay (body frame), the logged past EPDMS's history comfort reads."""
    t = (np.asarray(stamps) - now_us) / 1e6
    return np.column_stack([t, to_local(poses, origin), np.asarray(dynamics, np.float64).reshape(-1, 4)])


def add_map_fields(
    source: SceneSource,
    sample: dict[str, Any],
    map_name: str,
    origin: np.ndarray,
    roadblocks: list[str],
    red: list[list[int]],
    times: np.ndarray,
    past: np.ndarray,
    where: str,
) -> None:
    """``scoring`` (the PDM scorer's map context, ``red`` lane connectors per future keyframe at ``times``, the ego
    ``past``) and ``bev_semantic`` (rendered from it and the boxes) into ``sample``; needs ``source.maps``. A map
    error names ``where`` (the log's file and frame) too: the log's location or ids may be what is wrong."""
    assert source.maps is not None
    try:
        nuplan_map = navsim_map.load_map(source.maps, map_name)
        try:  # a damaged map (or the log's ids into it) fails deep in numpy/shapely: name the map file here
            context = navsim_map.scoring_context(nuplan_map, origin, source.map_radius, roadblocks, red, times)
            context["ego_past"] = past
            sample["scoring"] = context
            sample["bev_semantic"] = navsim_map.bev_semantic_raster(context, sample.get("boxes", np.zeros((0, 10))))
        except (TypeError, ValueError, KeyError, IndexError, shapely.errors.ShapelyError) as err:
            if isinstance(err, UserError):
                raise
            problem = f"{type(err).__name__}: {err}"
            raise navsim_map.MapError(
                f"{nuplan_map.path}: unusable around this scene, or the log's ids into it ({problem})"
            ) from err
    except navsim_map.MapError as err:
        raise type(err)(f"{where}: {err}") from err
