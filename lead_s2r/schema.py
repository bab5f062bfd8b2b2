"""Sample schema v1: the one contract between adapters, shards, data loading and scoring.

A sample is a plain ``dict``. ``__key__`` names it; every other key is a field listed in :data:`FIELDS`
(or a ``cam_<id>`` / ``semantic_<id>`` / ``depth_<id>`` family member). All geometry is in the ISO 8855 ego
frame at the sample's current time t0 with the origin at the rear-axle centre on the ground (see
``docs/conventions.md``). :func:`validate` is run on every sample a conversion writes.
"""

import math
import re
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np

from lead_s2r.errors import UserError
from lead_s2r.fields import fits, is_number

SCHEMA_VERSION = 1
KEY_PATTERN = re.compile(r"^[A-Za-z0-9_-]+$")


class Command(IntEnum):
    """Unified navigation command; each adapter keeps its dataset-native code as ``command_raw``."""

    UNKNOWN = 0
    LEFT = 1
    STRAIGHT = 2
    RIGHT = 3
    LANE_FOLLOW = 4
    CHANGE_LANE_LEFT = 5
    CHANGE_LANE_RIGHT = 6


_COMMAND4 = {
    Command.LANE_FOLLOW: Command.STRAIGHT,
    Command.CHANGE_LANE_LEFT: Command.LEFT,
    Command.CHANGE_LANE_RIGHT: Command.RIGHT,
}


def command4(command: int) -> Command:
    """Project a unified command onto the 4-way {UNKNOWN, LEFT, STRAIGHT, RIGHT} used by NAVSIM and WOD-E2E."""
    command = Command(command)
    return _COMMAND4.get(command, command)


class TargetDataset(IntEnum):
    """LEAD's camera rig codes (``lead/common/constants.py`` at 4489176), as LEAD's config.json stores them."""

    UNKNOWN = 0
    CARLA_LEADERBOARD2_3CAMERAS = 1
    CARLA_LEADERBOARD2_6CAMERAS = 2
    CARLA_LEADERBOARD2_1CAMERA = 3
    NAVSIM_4CAMERAS = 4
    WAYMO_E2E_2025_3CAMERAS = 5
    CARLA_PY123D_1CAMERA = 6


#: The numbering before LEAD added its one-camera rig (2026-01-11), which frames its expert wrote then may carry.
TARGET_DATASET_BEFORE_ONE_CAMERA = {
    1: TargetDataset.CARLA_LEADERBOARD2_3CAMERAS,
    2: TargetDataset.CARLA_LEADERBOARD2_6CAMERAS,
    3: TargetDataset.NAVSIM_4CAMERAS,
    4: TargetDataset.WAYMO_E2E_2025_3CAMERAS,
}


class BoxClass(IntEnum):
    """Unified object classes of the ``boxes`` field (column 9)."""

    VEHICLE = 0
    PEDESTRIAN = 1
    BICYCLE = 2
    TRAFFIC_CONE = 3
    BARRIER = 4
    CZONE_SIGN = 5
    GENERIC_OBJECT = 6
    TRAFFIC_LIGHT = 7
    STOP_SIGN = 8
    EMERGENCY_VEHICLE = 9


class BevClassNavsim(IntEnum):
    """NAVSIM TransFuser's 7-class BEV semantic layout (``bev_semantic`` with ``bev.classes == 'navsim'``)."""

    BACKGROUND = 0
    ROAD = 1
    WALKWAYS = 2
    CENTERLINE = 3
    STATIC_OBJECTS = 4
    VEHICLES = 5
    PEDESTRIANS = 6


class BevClassCarla(IntEnum):
    """LEAD's ChauffeurNet hdmap classes (``bev_semantic`` with ``bev.classes == 'carla_hdmap'``)."""

    UNLABELED = 0
    ROAD = 1
    SIDEWALK = 2
    LANE_MARKERS = 3
    LANE_MARKERS_BROKEN = 4
    STOP_SIGNS = 5
    TRAFFIC_GREEN = 6
    TRAFFIC_YELLOW = 7
    TRAFFIC_RED = 8


class SemanticClassCarla(IntEnum):
    """TransFuser's 10 perspective semantic classes, as LEAD stores them (``semantic_<cam>``)."""

    UNLABELED = 0
    VEHICLE = 1
    ROAD = 2
    TRAFFIC_LIGHT = 3
    PEDESTRIAN = 4
    ROAD_LINE = 5
    OBSTACLE = 6
    SPECIAL_VEHICLE = 7
    STOP_SIGN = 8
    BIKER = 9


CLASS_TABLES: dict[str, type[IntEnum]] = {
    "navsim": BevClassNavsim,
    "carla_hdmap": BevClassCarla,
    "carla_semantic": SemanticClassCarla,
}

#: The ``boxes`` columns vx, vy: both NaN where the source does not know a box's velocity (docs/schema.md).
BOX_VELOCITY = slice(7, 9)


class MapKind(IntEnum):
    """``polygon_kind`` codes of ``scoring.npz`` (nuPlan SemanticMapLayer names)."""

    ROADBLOCK = 0
    LANE = 1
    LANE_CONNECTOR = 2
    INTERSECTION = 3
    CARPARK_AREA = 4
    ROADBLOCK_CONNECTOR = 5
    WALKWAY = 6


class SchemaError(UserError, ValueError):
    """A sample breaks the schema; the message names the sample key and the field."""

    def __init__(self, key: str, field: str, problem: str) -> None:
        super().__init__(f"sample {key!r}, field {field!r}: {problem}")
        self.key = key
        self.field = field
        self.problem = problem


@dataclass(frozen=True)
class FieldSpec:
    """How one sample field is stored: tar member extension, array dtype and shape (None = any length)."""

    name: str
    ext: str
    dtype: str | None = None
    shape: tuple[int | None, ...] | None = None
    required: bool = False
    doc: str = ""


FIELDS: dict[str, FieldSpec] = {
    spec.name: spec
    for spec in (
        FieldSpec("meta", "json", required=True, doc="identity, ego state, vehicle, cameras, has flags, extras"),
        FieldSpec("past", "npy", "float32", (None, 4), required=True, doc="[t, x, y, yaw], t <= 0, ends at t = 0"),
        FieldSpec("future", "npy", "float32", (None, 4), doc="[t, x, y, yaw] at native rate, t > 0"),
        FieldSpec("lidar", "npy", "float32", (None, None), doc="points in the ego frame, columns in meta"),
        FieldSpec("radar", "npy", "float32", (None, 5), doc="x, y, z, radial velocity, sensor index"),
        FieldSpec("target_points", "npy", "float32", (3, 2), doc="previous, current, next target point"),
        FieldSpec("route", "npy", "float32", (None, 2), doc="dense route ahead"),
        FieldSpec(
            "boxes",
            "npy",
            "float32",
            (None, 10),
            doc="x, y, z, length, width, height, yaw, vx, vy (NaN: unknown), class",
        ),
        FieldSpec("agents_future", "npz", doc="poses (N,T,3), valid (N,T), t (T,)"),
        FieldSpec("bev_semantic", "png", "uint8", (None, None), doc="class ids, table named in meta.bev"),
        FieldSpec("raters", "npz", doc="trajectories (P,T,2), scores (P,)"),
        FieldSpec("scoring", "npz", doc="per-sample PDMS context"),
    )
}

#: Field families with one member per camera: ``cam_front`` -> ``cam_front.jpg``.
FAMILIES: dict[str, FieldSpec] = {
    "cam_": FieldSpec("cam_", "jpg", doc="JPEG bytes as the source stored them"),
    "semantic_": FieldSpec("semantic_", "png", "uint8", (None, None), doc="perspective class ids"),
    "depth_": FieldSpec("depth_", "png", "uint8", (None, None), doc="perspective depth, encoding in meta"),
}

META_REQUIRED = (
    "schema_version",
    "dataset",
    "split",
    "log_id",
    "frame_idx",
    "timestamp_us",
    "is_synthetic",
    "adapter",
    "adapter_version",
    "ego",
    "vehicle",
    "cameras",
    "has",
    "extras",
)
EGO_REQUIRED = ("speed", "velocity", "acceleration", "yaw_rate", "command", "command_raw")
VEHICLE_REQUIRED = ("length", "width", "wheel_base", "rear_axle_to_center")
CAMERA_REQUIRED = ("id", "native_name", "width", "height", "K", "distortion", "cam_to_ego")


def field_spec(name: str) -> FieldSpec:
    """The spec of a field name, resolving camera families; KeyError for unknown names."""
    if name in FIELDS:
        return FIELDS[name]
    for prefix, spec in FAMILIES.items():
        if name.startswith(prefix) and len(name) > len(prefix):
            return spec
    raise KeyError(name)


REQUIRED_FIELDS = tuple(name for name, spec in FIELDS.items() if spec.required)


def navsim_scene_token(sample: dict[str, Any]) -> str:
    """NAVSIM's scene token of a sample (the key of its CSV rows and GTRS's pickles); the sample key where the
    converter kept none."""
    return sample["meta"].get("extras", {}).get("navsim", {}).get("scene_token", sample["__key__"])


def make_key(*parts: object) -> str:
    """Join parts into a webdataset-safe key (no dots; anything outside [A-Za-z0-9_-] becomes '-')."""
    return "_".join(re.sub(r"[^A-Za-z0-9-]", "-", str(part)) for part in parts)


def validate(sample: dict[str, Any]) -> None:
    """Raise :class:`SchemaError` naming the field if ``sample`` is not a valid schema v1 sample."""
    key = sample.get("__key__")
    if not isinstance(key, str) or not KEY_PATTERN.match(key):
        raise SchemaError(str(key), "__key__", "must be a non-empty string of [A-Za-z0-9_-] (no dots)")
    for name in REQUIRED_FIELDS:
        if name not in sample:
            raise SchemaError(key, name, "required field is missing")
    for name, value in sample.items():
        if name == "__key__":
            continue
        try:
            spec = field_spec(name)
        except KeyError:
            raise SchemaError(key, name, "unknown field") from None
        _check_value(key, name, spec, value)
    _check_meta(key, sample)
    check_trajectory(key, "past", sample["past"], past=True)
    if "future" in sample:
        check_trajectory(key, "future", sample["future"], past=False)
    if "boxes" in sample:
        _check_boxes(key, sample["boxes"])
    if "target_points" in sample:
        rows = sample["target_points"]
        partial = np.isnan(rows).any(axis=1) & ~np.isnan(rows).all(axis=1)
        if partial.any() or np.isinf(rows).any():
            raise SchemaError(key, "target_points", "a row must be all finite or all NaN (absent)")


def _check_boxes(key: str, boxes: np.ndarray) -> None:
    """Every box value finite, except a velocity the source does not know: vx and vy both NaN."""
    velocity = boxes[:, BOX_VELOCITY]
    unknown = np.isnan(velocity).all(axis=1)
    if not (np.isfinite(np.delete(boxes, BOX_VELOCITY, axis=1)).all() and np.isfinite(velocity[~unknown]).all()):
        raise SchemaError(key, "boxes", "contains NaN or infinite values (vx, vy may both be NaN: velocity unknown)")


def _check_value(key: str, name: str, spec: FieldSpec, value: Any) -> None:
    if spec.ext == "json":
        if not isinstance(value, dict):
            raise SchemaError(key, name, f"expected a dict, got {type(value).__name__}")
    elif spec.ext == "jpg":
        if not isinstance(value, bytes | bytearray) or value[:2] != b"\xff\xd8":
            raise SchemaError(key, name, "expected JPEG bytes (starting with FFD8)")
    elif spec.ext == "npz":
        if not isinstance(value, dict) or not all(isinstance(v, np.ndarray) for v in value.values()):
            raise SchemaError(key, name, "expected a dict of numpy arrays")
    elif not isinstance(value, np.ndarray):
        raise SchemaError(key, name, f"expected a numpy array, got {type(value).__name__}")
    elif value.dtype != np.dtype(spec.dtype):
        raise SchemaError(key, name, f"expected dtype {spec.dtype}, got {value.dtype}")
    elif spec.shape is not None:
        ok = value.ndim == len(spec.shape) and all(
            want is None or want == got for want, got in zip(spec.shape, value.shape, strict=False)
        )
        if not ok:
            want = tuple("N" if dim is None else dim for dim in spec.shape)
            raise SchemaError(key, name, f"expected shape {want}, got {value.shape}")


def check_trajectory(key: str, name: str, rows: np.ndarray, past: bool) -> None:
    """Raise :class:`SchemaError` unless ``rows`` is a valid ``past`` (or future) trajectory of sample ``key``."""
    if len(rows) == 0:
        raise SchemaError(key, name, "is empty")
    if not np.isfinite(rows[:, :3]).all():
        raise SchemaError(key, name, "t, x, y must be finite (yaw alone may be NaN)")
    if np.isinf(rows[:, 3]).any():
        raise SchemaError(key, name, "yaw must not be infinite")
    if (np.diff(rows[:, 0]) <= 0).any():
        raise SchemaError(key, name, "t must be strictly increasing")
    if past and (rows[-1, 0] != 0 or (rows[:, 0] > 0).any()):
        raise SchemaError(key, name, "past must have t <= 0 and end with the t = 0 row")
    if not past and rows[0, 0] <= 0:
        raise SchemaError(key, name, "future must have t > 0")
    yaw = rows[:, 3][~np.isnan(rows[:, 3])]
    if ((yaw < -math.pi) | (yaw > math.pi)).any():
        raise SchemaError(key, name, "yaw must lie in [-pi, pi]")


def _require(key: str, where: str, mapping: Any, names: tuple[str, ...]) -> None:
    if not isinstance(mapping, dict):
        raise SchemaError(key, where, "expected a dict")
    for name in names:
        if name not in mapping:
            raise SchemaError(key, f"{where}.{name}", "required entry is missing")


def _is_matrix(value: Any, size: int) -> bool:
    """Whether ``value`` is a ``size`` x ``size`` matrix of finite numbers as JSON holds it (rows of a ragged list
    would make numpy raise instead of answering)."""
    return fits(value, list[list[float]]) and len(value) == size and all(len(row) == size for row in value)


def _check_meta(key: str, sample: dict[str, Any]) -> None:
    meta = sample["meta"]
    _require(key, "meta", meta, META_REQUIRED)
    if meta["schema_version"] != SCHEMA_VERSION:
        raise SchemaError(key, "meta.schema_version", f"expected {SCHEMA_VERSION}, got {meta['schema_version']!r}")
    _require(key, "meta.ego", meta["ego"], EGO_REQUIRED)
    _require(key, "meta.vehicle", meta["vehicle"], VEHICLE_REQUIRED)
    ego = meta["ego"]
    for name in ("speed", "yaw_rate"):
        if not is_number(ego[name]):
            raise SchemaError(key, f"meta.ego.{name}", f"expected a finite number, got {ego[name]!r}")
    for name in ("velocity", "acceleration"):
        vec = ego[name]
        if not (fits(vec, list[float]) and len(vec) == 2):
            raise SchemaError(key, f"meta.ego.{name}", f"expected 2 finite numbers, got {vec!r}")
    if ego["command"] not in {int(c) for c in Command}:
        raise SchemaError(key, "meta.ego.command", f"not a Command value: {ego['command']!r}")
    has = meta["has"]
    if not isinstance(has, dict):
        raise SchemaError(key, "meta.has", "expected a dict of field name -> bool")
    for name in sorted(set(sample) - {"__key__", *REQUIRED_FIELDS}):
        if has.get(name) is not True:
            raise SchemaError(key, f"meta.has.{name}", "field is present but not flagged true")
    for name, flag in has.items():
        if flag and name not in sample:
            raise SchemaError(key, f"meta.has.{name}", "flagged true but the field is missing")
    if not isinstance(meta["cameras"], list):
        raise SchemaError(key, "meta.cameras", "expected a list of cameras")
    for i, camera in enumerate(meta["cameras"]):
        _require(key, f"meta.cameras[{i}]", camera, CAMERA_REQUIRED)
        if not (_is_matrix(camera["K"], 3) and _is_matrix(camera["cam_to_ego"], 4)):
            raise SchemaError(key, f"meta.cameras[{i}]", "K must be 3x3 and cam_to_ego 4x4 finite numbers")
    if "lidar" in sample:
        columns = meta.get("lidar_columns")
        if not isinstance(columns, list) or len(columns) != sample["lidar"].shape[1]:
            raise SchemaError(key, "meta.lidar_columns", "must list one name per lidar column")
