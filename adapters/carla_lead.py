"""LEAD CARLA route folders -> schema v1 samples (one log = one route folder, one sample = one 4 Hz frame).

LEAD stores everything in CARLA's ego frame (x forward, y right, yaw clockwise) with the origin at the vehicle
centre; ego poses go through ``geometry.carla_poses_to_iso``, points through ``carla_points_to_iso``, and other
actors' box centres move like points (only the frame origin goes to the rear axle, not each box's own centre).
The perturbated rig (``rig="perturbated"``) is LEAD's recovery augmentation: the sensors were rendered from a
rig shifted sideways by ``perturbation_translation`` and turned by ``perturbation_rotation`` degrees, so every
label is re-expressed in that virtual ego frame, as LEAD's own loader does. Facts: ``docs/datasets/carla_lead.md``.

The camera rig is not one rig: LEAD collects with the rig of ``dataset_information.target_dataset`` (3 or 6
Leaderboard cameras, one wide camera, or cameras matched to NAVSIM's), so the calibration is read from each frame's
meta, and the stored mosaic's width (read from the JPEG header with Pillow, never decoding it) must match that rig's,
or the calibration written beside it would be wrong.
"""

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from lead_s2r.fields import fits
from lead_s2r.formats.carla_rig import (
    CAMERA_RIGS,
    DEFAULT_TARGET_DATASET,
    EGO_VEHICLE,
    MOSAIC_ID,
    ROAD_OPTION,
    camera_calibration,
)
from lead_s2r.geometry import (
    CARLA_REAR_AXLE_TO_CENTER,
    carla_points_to_iso,
    carla_poses_to_iso,
    centre_points_to_rear_axle,
    flip_y,
    points_to_local,
    rotate,
    to_local,
)
from lead_s2r.image_headers import jpeg_size
from lead_s2r.registry import Adapter, LogRef, SkipLog
from lead_s2r.schema import SCHEMA_VERSION, TARGET_DATASET_BEFORE_ONE_CAMERA, BoxClass, Command, make_key
from lead_s2r_adapters.carla_lead_io import (
    RADAR_KEYS,
    LeadFormatError,
    array,
    field,
    frame_file,
    is_route,
    read_jpeg,
    read_laz,
    read_pickle,
    read_png,
    read_radar,
    route_frames,
    route_skip_reason,
    track_poses,
)

FPS = 20.0  # simulator and future-label rate
FRAME_STEP = 5  # a frame is saved every 5th 20 Hz tick: 4 Hz
DEPTH_MAX_M, DEPTH_RATIO = 50.0, 4
HDMAP_PX_PER_M, HDMAP_SIZE = 2.0, 256
EMERGENCY_TYPES = ("ambulance", "firetruck", "police")
RIGS = ("normal", "perturbated", "both")


def box_class(box: dict[str, Any]) -> BoxClass:
    """LEAD bbox class (+ CARLA blueprint) -> unified box class."""
    cls, type_id = box.get("class"), str(box.get("type_id", ""))
    if cls == "car":
        if any(name in type_id for name in EMERGENCY_TYPES):
            return BoxClass.EMERGENCY_VEHICLE
        return BoxClass.BICYCLE if box.get("base_type") == "bicycle" else BoxClass.VEHICLE
    if cls == "static":
        if "trafficcone" in type_id:
            return BoxClass.TRAFFIC_CONE
        return BoxClass.CZONE_SIGN if "warning" in type_id or "construction" in type_id else BoxClass.GENERIC_OBJECT
    fixed = {
        "walker": BoxClass.PEDESTRIAN,
        "static_prop_car": BoxClass.VEHICLE,
        "traffic_light": BoxClass.TRAFFIC_LIGHT,
        "stop_sign": BoxClass.STOP_SIGN,
    }
    return fixed.get(cls, BoxClass.GENERIC_OBJECT)


def target_dataset(meta: dict[str, Any], path: Path) -> str:
    """The rig a frame was recorded with: ``dataset_information.target_dataset`` (a name, or LEAD's enum number)."""
    info = meta.get("dataset_information")
    if info is None:
        return DEFAULT_TARGET_DATASET
    value = field(info, "target_dataset", path)
    # a number in the expert's numbering of its time (a wrong guess is caught by the mosaic-width check), or
    # "TargetDataset.NAVSIM_4CAMERAS" as str() of the enum writes it
    if fits(value, int):
        code = TARGET_DATASET_BEFORE_ONE_CAMERA.get(int(value))
        name = code.name if code is not None else None
    else:
        name = str(value).rsplit(".", 1)[-1]
    if name not in CAMERA_RIGS:
        raise LeadFormatError(
            path, f"unknown camera rig {value!r}; known: {', '.join(CAMERA_RIGS)}", "dataset_information.target_dataset"
        )
    return name


def mosaic_height(data: bytes, rig: str, path: Path) -> int:
    """Rows of a stored mosaic, which must have the rig's width and its kept (or full rendered) height, or the
    calibration written beside it would be wrong."""
    size = jpeg_size(data)
    if size is None:
        raise LeadFormatError(path, "unreadable JPEG header (no frame header with the image size)")
    width, height = size
    cameras = CAMERA_RIGS[rig]
    want_width, heights = sum(c.width for c in cameras), (cameras[0].stored_height, cameras[0].height)
    if width != want_width or height not in heights:
        raise LeadFormatError(
            path,
            f"mosaic is {width}x{height}, but rig {rig} (dataset_information.target_dataset) stores {want_width}x"
            f"{heights[0]}; the route's metas name the wrong rig",
        )
    return height


def hdmap_pixel_to_ego() -> list[list[float]]:
    """Affine (2x3) from (column, row, 1) of the stored ``bev_semantic`` to ISO ego x, y (pixel centres): LEAD's
    raster has rows along CARLA y and columns along x around the vehicle centre, and is stored rotated (losslessly,
    ``np.rot90``) so that row 0 is the front and column 0 the left."""
    res, half = 1.0 / HDMAP_PX_PER_M, (HDMAP_SIZE - 1) / 2
    return [[0.0, -res, half * res + CARLA_REAR_AXLE_TO_CENTER], [-res, 0.0, half * res]]


class _Frame:
    """Moves CARLA ego-centre geometry of one frame into the chosen rig's ISO rear-axle frame."""

    def __init__(self, view: np.ndarray) -> None:
        self.view = view  # the rig's pose (x, y, yaw) in the CARLA ego-centre frame

    def poses(self, poses: np.ndarray) -> np.ndarray:
        """Ego poses: each one's origin also moves from the vehicle centre to the rear axle."""
        return carla_poses_to_iso(to_local(poses, self.view))

    def box_poses(self, poses: np.ndarray) -> np.ndarray:
        """Other actors' box-centre poses: the frame changes, but a box centre stays a box centre."""
        return centre_points_to_rear_axle(flip_y(to_local(poses, self.view), (1, 2)), CARLA_REAR_AXLE_TO_CENTER)

    def points(self, points: np.ndarray) -> np.ndarray:
        return carla_points_to_iso(points_to_local(points, self.view))

    def vectors(self, vectors: np.ndarray) -> np.ndarray:
        return flip_y(rotate(np.asarray(vectors, np.float64), -float(self.view[2])))


class CarlaLeadAdapter(Adapter):
    """Reads route folders as the LEAD expert writes them (``<root>/data/<Scenario>/<Route>/``). Options: ``rig``
    normal | perturbated | both (two samples per frame, keys ``..._perturbated_NNNN``); ``split`` for every route,
    except towns in ``heldout_towns`` (comma-separated) which get ``heldout_split``; ``tp_distance`` selects the
    ``next_target_points_<d>`` planner (LEAD trains with 3.25 m); ``skip_first`` / ``skip_last`` frames per route
    (LEAD pretraining: 1 / 1); ``keep_failed`` keeps finished routes that LEAD's route filter drops for their
    infractions."""

    name: ClassVar[str] = "carla_lead"
    #: 2: box and agent-future centres are no longer shifted along their heading;
    #: 3: camera calibration of the route's own rig (dataset_information.target_dataset), not always 3 cameras;
    #: 4: extras traffic_light_affects_ego and unusual_traffic_lights (LEAD's traffic-light labels)
    version: ClassVar[str] = "4"
    extras: ClassVar[str | None] = "carla"

    def __init__(
        self,
        rig: str = "normal",
        split: str = "train",
        heldout_towns: str = "",
        heldout_split: str = "val",
        tp_distance: float = 3.25,
        skip_first: int = 0,
        skip_last: int = 0,
        keep_failed: bool = False,
    ) -> None:
        if rig not in RIGS:
            raise ValueError(f"rig must be one of {', '.join(RIGS)}, got {rig!r}")
        if skip_first < 0 or skip_last < 0:
            raise ValueError("skip_first and skip_last must be >= 0")
        self.rig, self.split, self.heldout_split = rig, split, heldout_split
        self.heldout_towns = tuple(town.strip() for town in heldout_towns.split(",") if town.strip())
        self.tp_distance, self.skip_first, self.skip_last = float(tp_distance), skip_first, skip_last
        self.keep_failed = keep_failed

    def list_logs(self, src: Path) -> list[LogRef]:
        """Route folders under ``src/data/*/`` (or ``src/*/`` when ``src`` is the data folder), sorted. A route
        folder holds ``bboxes/``, ``metas/`` or ``results.json``: another dataset's folders two levels down (NAVSIM's
        ``navsim_logs/mini``) are not routes to skip one by one, they are the wrong ``--src``."""
        src = Path(src)
        root = src / "data" if (src / "data").is_dir() else src
        if not root.is_dir():
            raise FileNotFoundError(f"{root}: not a folder of LEAD scenarios")
        logs = []
        for folder in sorted(p for p in root.glob("*/*") if is_route(p)):
            town = folder.name.split("_Rep")[0]
            split = self.heldout_split if town in self.heldout_towns else self.split
            log_id = f"{folder.parent.name}/{folder.name}"
            logs.append(LogRef(log_id, split, str(folder), {"town": town, "scenario": folder.parent.name}))
        return logs

    def describe(self) -> dict[str, Any]:
        return {
            "dataset": "carla_lead",
            "frame_rate_hz": FPS / FRAME_STEP,
            "future": {"rate_hz": FPS, "horizon_s": 3.0},
            "past": {"rate_hz": FPS, "horizon_s": 3.0},
            "agents_future": {"rate_hz": FPS, "horizon_s": 2.0},
            "rig": self.rig,
            "tp_distance": self.tp_distance,
            "camera_rigs": "per route, from dataset_information.target_dataset (meta.cameras, extras target_dataset)",
            "source_frame": "CARLA ego (x forward, y right), vehicle centre; converted to ISO 8855 rear axle",
        }

    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        folder = Path(log.path)
        reason = route_skip_reason(folder, self.keep_failed)
        if reason is not None:
            raise SkipLog(f"{log.log_id}: {reason}")
        frames = route_frames(folder)
        rigs = ("normal", "perturbated") if self.rig == "both" else (self.rig,)
        for name in frames[self.skip_first : len(frames) - self.skip_last]:
            meta_path, boxes_path = folder / "metas" / f"{name}.pkl", folder / "bboxes" / f"{name}.pkl"
            meta = read_pickle(meta_path)
            boxes = read_pickle(boxes_path)
            if not isinstance(boxes, list) or not all(isinstance(box, dict) for box in boxes):
                raise LeadFormatError(boxes_path, "expected a list of dicts (one per box)")
            others = [box for box in boxes if box.get("class") != "ego_car"]
            lidar_path = frame_file(folder, "lidar", name, ".laz")
            lidar = None if lidar_path is None else read_laz(lidar_path)  # one LiDAR for both rigs
            for rig in rigs:
                try:
                    yield self._sample(log, folder, name, meta, meta_path, others, lidar, rig)
                except (TypeError, KeyError, IndexError, AttributeError) as err:  # a value of an unexpected type
                    problem = f"a value of an unexpected type ({type(err).__name__}: {err})"
                    raise LeadFormatError(meta_path, f"{problem}, here or in {boxes_path}") from err

    def _view(self, meta: dict[str, Any], path: Path, rig: str) -> np.ndarray:
        if rig == "normal":
            return np.zeros(3)
        translation = float(field(meta, "perturbation_translation", path))
        rotation = float(field(meta, "perturbation_rotation", path))
        return np.array([0.0, translation, math.radians(rotation)])

    def _sample(
        self,
        log: LogRef,
        folder: Path,
        name: str,
        meta: dict[str, Any],
        path: Path,
        others: list[dict[str, Any]],
        lidar: tuple[np.ndarray, np.ndarray] | None,
        rig: str,
    ) -> dict[str, Any]:
        """One rig's sample of a frame; ``others`` are the frame's boxes without the ego, ``lidar`` its point
        cloud and sweep index, both read once for every rig."""
        frame = _Frame(self._view(meta, path, rig))
        suffix = "_perturbated" if rig == "perturbated" else ""
        key = make_key(log.log_id, name) if rig == "normal" else make_key(log.log_id, "perturbated", name)
        sample: dict[str, Any] = {"__key__": key, "past": self._past(meta, path, frame)}
        future = self._future(meta, path, frame)
        if future is not None:
            sample["future"] = future
        command_raw, sample["target_points"] = self._navigation(meta, path, frame)
        route = array(meta, "route", path, columns=2) if "route" in meta else None
        if route is not None and len(route):
            sample["route"] = frame.points(route[:, :2]).astype(np.float32)
        sample.update(self._boxes(others, folder / "bboxes" / f"{name}.pkl", frame))
        sample.update(self._sensors(folder, name, suffix))
        camera_rig, cameras = target_dataset(meta, path), []
        if f"cam_{MOSAIC_ID}" in sample:
            height = mosaic_height(sample[f"cam_{MOSAIC_ID}"], camera_rig, folder / f"rgb{suffix}" / f"{name}.jpg")
            cameras = camera_calibration(camera_rig, height)
        if lidar is not None:  # LEAD re-aligns the one LiDAR to the perturbated rig in software
            points, sweep = lidar
            sample["lidar"] = np.column_stack([frame.points(points), -sweep / FPS]).astype(np.float32)
        extras = self._extras(log, meta, others, rig)
        extras["carla_lead"]["target_dataset"] = camera_rig
        sample["meta"] = self._meta(log, meta, path, int(name), frame, command_raw, sample, extras)
        sample["meta"]["cameras"] = cameras
        return sample

    def _future(self, meta: dict[str, Any], path: Path, frame: _Frame) -> np.ndarray | None:
        """``future_positions``/``future_yaws`` at 20 Hz, index 0 = now (dropped), in the current ego frame."""
        future = track_poses(meta, "future", path)
        if len(future) < 2:
            return None
        t = np.arange(1, len(future)) / FPS
        return np.column_stack([t, frame.poses(future[1:])]).astype(np.float32)

    def _past(self, meta: dict[str, Any], path: Path, frame: _Frame) -> np.ndarray:
        """``past_positions``/``past_yaws`` at 20 Hz, newest first (index 0 = now); just t = 0 when absent."""
        has_past = "past_positions" in meta and "past_yaws" in meta
        past = track_poses(meta, "past", path)[::-1] if has_past else np.zeros((0, 3))
        if len(past) == 0:
            past = np.zeros((1, 3))
        t = (np.arange(len(past)) - (len(past) - 1)) / FPS
        return np.column_stack([t, frame.poses(past)]).astype(np.float32)

    def _navigation(self, meta: dict[str, Any], path: Path, frame: _Frame) -> tuple[int, np.ndarray]:
        """Previous / current / next target point (NaN row = absent) and the command of the previous one; world
        points go to the ego frame as ``R(theta)^T (p - pos_global)``, consecutive duplicates merged."""
        suffix = f"_{self.tp_distance}"
        points = array(meta, f"next_target_points{suffix}", path, columns=2)[:, :2]
        commands = list(field(meta, f"next_commands{suffix}", path))
        origin = np.r_[array(meta, "pos_global", path)[:2], float(field(meta, "theta", path))]
        local = points_to_local(points, origin)
        if len(local) > 1:
            keep = np.r_[True, np.any(np.abs(np.diff(local, axis=0)) > 1e-6, axis=1)]
            local = local[keep]
        rows = np.full((3, 2), np.nan)
        if len(local):
            rows[: min(3, len(local))] = frame.points(local[:3])
        command_raw = int(commands[0]) if commands else -1
        return command_raw, rows.astype(np.float32)

    def _boxes(self, others: list[dict[str, Any]], path: Path, frame: _Frame) -> dict[str, Any]:
        """``boxes`` (N, 10) and, for boxes with ``future_positions`` (20 Hz, index 0 = now), ``agents_future``."""
        rows = np.zeros((len(others), 10), np.float64)
        centres = np.zeros((len(others), 3))  # x, y, yaw in the CARLA ego-centre frame
        speeds = np.zeros(len(others))
        horizon = max((len(box["future_positions"]) - 1 for box in others if "future_positions" in box), default=0)
        futures = np.full((len(others), horizon, 3), np.nan)
        for i, box in enumerate(others):
            extent = array(box, "extent", path)
            position = array(box, "position", path)
            yaw = float(field(box, "yaw", path))
            if extent.shape != (3,) or position.shape != (3,):
                raise LeadFormatError(path, f"box {i}: extent and position must hold 3 numbers", "extent/position")
            speeds[i] = float(box.get("speed", 0.0))
            if not np.isfinite([*extent, *position, yaw, speeds[i]]).all():  # None reads as NaN in a float array
                raise LeadFormatError(path, f"box {i}: extent, position, yaw and speed must be finite numbers")
            centres[i] = position[0], position[1], yaw
            rows[i, 2:6] = position[2], *(2 * extent)
            rows[i, 9] = box_class(box)
            if "future_positions" in box:
                future = track_poses(box, "future", path, f"box {i}: ")[1:]
                futures[i, : len(future)] = future
        rows[:, [0, 1, 6]] = frame.box_poses(centres)
        heading = np.column_stack([np.cos(centres[:, 2]), np.sin(centres[:, 2])])
        rows[:, 7:9] = frame.vectors(speeds[:, None] * heading)
        out: dict[str, Any] = {"boxes": rows.astype(np.float32)}
        if horizon:
            poses = frame.box_poses(futures)  # NaN padding stays NaN
            valid = ~np.isnan(poses[..., 0])
            t = (np.arange(1, horizon + 1) / FPS).astype(np.float32)
            out["agents_future"] = {"poses": poses.astype(np.float32), "valid": valid, "t": t}
        return out

    def _sensors(self, folder: Path, name: str, suffix: str) -> dict[str, Any]:
        """Camera mosaic, perspective labels, hdmap and radar of one frame and rig, each where its file exists."""
        out: dict[str, Any] = {}
        for sensor, ext, key, read in (
            ("rgb", ".jpg", f"cam_{MOSAIC_ID}", read_jpeg),
            ("semantics", ".png", f"semantic_{MOSAIC_ID}", read_png),
            ("depth", ".png", f"depth_{MOSAIC_ID}", read_png),
            ("hdmap", ".png", "bev_semantic", lambda path: np.ascontiguousarray(np.rot90(read_png(path)))),
        ):
            path = frame_file(folder, f"{sensor}{suffix}", name, ext)
            if path is not None:
                out[key] = read(path)
        radar = frame_file(folder, f"radar{suffix}", name, ".npz")
        if radar is not None:  # the perturbated radar was recorded from the perturbated rig, in its frame
            clouds = read_radar(radar)
            rows = [
                np.column_stack([carla_points_to_iso(c[:, :3]), c[:, 3], np.full(len(c), i)])
                for i, c in enumerate(clouds)
            ]
            out["radar"] = np.concatenate(rows).astype(np.float32)
        return out

    def _extras(self, log: LogRef, meta: dict[str, Any], others: list[dict[str, Any]], rig: str) -> dict[str, Any]:
        lights = [box for box in others if box.get("class") == "traffic_light"]
        return {
            "carla_lead": {
                "town": meta.get("town", log.extra.get("town")),
                "scenario": meta.get("scenario", log.extra.get("scenario")),
                "route": Path(log.path).name,
                "weather": meta.get("weather_setting"),
                "jpeg_quality": meta.get("jpeg_storage_quality"),
                "rig": rig,
                "perturbation_translation": meta.get("perturbation_translation"),
                "perturbation_rotation_deg": meta.get("perturbation_rotation"),
                "target_speed": None if meta.get("target_speed") is None else float(meta["target_speed"]),
                "brake": bool(meta.get("brake", False)),
                "box_ids": [int(box.get("id", -1)) for box in others],
                "box_classes": [str(box.get("class")) for box in others],
                "traffic_light_states": [str(box.get("state")) for box in lights],
                "traffic_light_affects_ego": [bool(box.get("affects_ego", False)) for box in lights],
                # LEAD labels red lights of these two kinds apart (TRAFFIC_RED_NOT_NORMAL)
                "unusual_traffic_lights": bool(meta.get("over_head_traffic_light") or meta.get("europe_traffic_light")),
            }
        }

    def _meta(
        self,
        log: LogRef,
        meta: dict[str, Any],
        path: Path,
        index: int,
        frame: _Frame,
        command_raw: int,
        sample: dict[str, Any],
        extras: dict[str, Any],
    ) -> dict[str, Any]:
        speed = float(field(meta, "speed", path))
        acceleration = [float(meta.get("accel_x", 0.0)), float(meta.get("accel_y", 0.0))]
        out: dict[str, Any] = {
            "schema_version": SCHEMA_VERSION,
            "dataset": "carla_lead",
            "split": log.split,
            "log_id": log.log_id,
            "frame_idx": index,
            "timestamp_us": index * FRAME_STEP * 1_000_000 // int(FPS),
            "is_synthetic": True,
            "location": extras["carla_lead"]["town"],
            "adapter": self.name,
            "adapter_version": self.version,
            "ego": {
                "speed": speed,
                "velocity": frame.vectors(np.array([speed, 0.0])).tolist(),
                "acceleration": frame.vectors(np.array(acceleration)).tolist(),
                "yaw_rate": -float(meta.get("angular_velocity_z", 0.0)),
                "command": int(ROAD_OPTION.get(command_raw, Command.UNKNOWN)),
                "command_raw": command_raw,
            },
            "vehicle": dict(EGO_VEHICLE),
            "has": {name: True for name in sample if name != "__key__"},
            "extras": extras,
        }
        optional = ("future", "lidar", "radar", "route", f"cam_{MOSAIC_ID}", "bev_semantic", "agents_future")
        for name in (*optional, f"depth_{MOSAIC_ID}", f"semantic_{MOSAIC_ID}"):
            out["has"].setdefault(name, False)
        if "lidar" in sample:
            out["lidar_columns"] = ["x", "y", "z", "time"]
        if "radar" in sample:
            out["radar_sensors"] = list(RADAR_KEYS)
        if "bev_semantic" in sample:
            out["bev"] = {"classes": "carla_hdmap", "pixel_to_ego": hdmap_pixel_to_ego()}
        if f"depth_{MOSAIC_ID}" in sample:
            out["depth"] = {"encoding": "linear_uint8", "max_m": DEPTH_MAX_M, "downscale": DEPTH_RATIO}
        if f"semantic_{MOSAIC_ID}" in sample:
            out["semantic"] = {"classes": "carla_semantic"}
        return out
