"""NAVSIM v2 synthetic scenes (``<split>/synthetic_scene_pickles/<17hex>.pkl``) -> schema v1 samples.

A synthetic scene pickle is the dict ``Scene.save_to_disk`` writes. ``scene_metadata``, ``frames`` (history only,
each with ``annotations`` in the frame's ego frame and ``ego_status`` in the global frame) and the cameras of the
current frame are plain data. The future is stored as nuPlan objects: ``extended_detections_tracks``
(``DetectionsTracks``, global boxes) and ``extended_traffic_light_data`` (``TrafficLightStatuses``), one per 2 Hz
keyframe after the current frame. The restricted unpickler admits exactly the nuPlan classes in
:data:`NUPLAN_RECORDS`, as plain :class:`~lead_s2r.formats.restricted_pickle.Record` data: nothing from nuPlan runs.

Synthetic scenes have no logged future ego (NAVSIM's human trajectory is None for them), so the sample has no
``future`` and ``meta.is_synthetic`` is true; no lidar either. The camera extrinsics are ``sensor2lidar``, as in the
logs, and ``cam_to_ego`` uses the ``lidar2ego`` of the scene's original log (the same vehicle and sensor rig).
"""

from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.formats.restricted_pickle import Record
from lead_s2r.geometry import to_local
from lead_s2r.registry import LogRef
from lead_s2r.schema import make_key
from lead_s2r_adapters import navsim_map
from lead_s2r_adapters.navsim_io import (
    BOX_CLASSES,
    CAMERAS,
    OBJECT_TYPES,
    SCENE_ANNOTATIONS,
    NavsimFormatError,
    lidar2ego,
    load_log,
    load_pickle,
    read_annotations,
    read_camera,
    required,
)
from lead_s2r_adapters.navsim_scene import (
    SceneFrame,
    SceneSource,
    TrackStep,
    add_map_fields,
    agents_future,
    ego_meta,
    ego_past,
    scene_meta,
)

_ACTOR = "nuplan.common.actor_state"
_MAPS = "nuplan.common.maps.maps_datatypes"
#: The nuPlan classes a synthetic scene pickle holds, read as plain records.
NUPLAN_RECORDS = frozenset(
    {
        ("nuplan.planning.simulation.observation.observation_type", "DetectionsTracks"),
        (f"{_ACTOR}.tracked_objects", "TrackedObjects"),
        (f"{_ACTOR}.agent", "Agent"),
        (f"{_ACTOR}.static_object", "StaticObject"),
        (f"{_ACTOR}.oriented_box", "OrientedBox"),
        (f"{_ACTOR}.state_representation", "StateSE2"),
        (f"{_ACTOR}.state_representation", "StateVector2D"),
        (f"{_ACTOR}.scene_object", "SceneObjectMetadata"),
        (f"{_ACTOR}.tracked_objects_types", "TrackedObjectType"),
        (_MAPS, "TrafficLightStatuses"),
        (_MAPS, "TrafficLightStatusData"),
        (_MAPS, "TrafficLightStatusType"),
    }
)
SCENE_KEYS = ("scene_metadata", "frames", "extended_traffic_light_data", "extended_detections_tracks")
RED = 2  # nuPlan TrafficLightStatusType.RED


def load_scene(path: Path) -> dict[str, Any]:
    """A synthetic scene pickle as a dict, its nuPlan objects as records; checked for NAVSIM's top-level keys."""
    scene = load_pickle(path, "NAVSIM synthetic scene pickle", NUPLAN_RECORDS)
    if not isinstance(scene, dict) or any(key not in scene for key in SCENE_KEYS):
        raise NavsimFormatError(f"{path}: a synthetic scene must be a dict with keys {', '.join(SCENE_KEYS)}")
    if not scene["frames"]:
        raise NavsimFormatError(f"{path}: field 'frames' is empty")
    return scene


def _record(value: Any, name: str, where: str) -> Record:
    if not isinstance(value, Record) or not value.path.endswith(f".{name}"):
        raise NavsimFormatError(f"{where}: expected a nuPlan {name}, got {value!r:.120}")
    return value


def _numbers(value: Any, name: str, fields: tuple[str, ...], where: str) -> tuple[float, ...]:
    """A nuPlan ``name`` record's ``fields`` from its constructor arguments (``__reduce__``) or its attributes."""
    value = _record(value, name, where)
    if len(value.args) == len(fields):
        return tuple(float(v) for v in value.args)
    return tuple(float(value.state[field]) for field in fields)


def tracked_objects(detections: Record, where: str) -> TrackStep:
    """The boxes of a ``DetectionsTracks`` as a :class:`~navsim_scene.TrackStep` (global poses and velocities)."""
    container = _record(
        _record(detections, "DetectionsTracks", where).state.get("tracked_objects"), "TrackedObjects", where
    )
    tracks, poses, velocities, sizes, classes = [], [], [], [], []
    for i, item in enumerate(container.state.get("tracked_objects", [])):
        at = f"{where} object {i}"
        if not isinstance(item, Record) or not item.path.endswith((".Agent", ".StaticObject")):
            raise NavsimFormatError(f"{at}: expected a nuPlan Agent or StaticObject, got {item!r:.120}")
        box = _record(item.state.get("_box"), "OrientedBox", at)
        kind = int(_record(item.state.get("_tracked_object_type"), "TrackedObjectType", at).args[0])
        if not 0 <= kind < len(OBJECT_TYPES):
            raise NavsimFormatError(f"{at}: TrackedObjectType {kind} is not an OpenScene class")
        metadata = _record(item.state.get("_metadata"), "SceneObjectMetadata", at)
        velocity = item.state.get("_velocity")
        tracks.append(str(metadata.state["track_token"]))
        classes.append(BOX_CLASSES[OBJECT_TYPES[kind]])
        poses.append(_numbers(box.state["_center"], "StateSE2", ("x", "y", "heading"), at))
        sizes.append((float(box.state["_length"]), float(box.state["_width"]), float(box.state["_height"])))
        velocities.append((0.0, 0.0) if velocity is None else _numbers(velocity, "StateVector2D", ("x", "y"), at))
    return TrackStep(
        tracks=tracks,
        poses=np.array(poses, np.float64).reshape(-1, 3),
        velocity=np.array(velocities, np.float64).reshape(-1, 2),
        velocity_yaw=0.0,
        size=np.array(sizes, np.float64).reshape(-1, 3),
        classes=np.array(classes, np.int64),
    )


def red_lights(statuses: Record, where: str) -> list[int]:
    """Lane connector ids whose light is red in a ``TrafficLightStatuses``."""
    red = []
    for data in _record(statuses, "TrafficLightStatuses", where).state.get("traffic_lights", []):
        data = _record(data, "TrafficLightStatusData", where)
        if int(_record(data.state["status"], "TrafficLightStatusType", where).args[0]) == RED:
            red.append(int(data.state["lane_connector_id"]))
    return red


@lru_cache(maxsize=32)
def lidar2ego_of(log_path: str) -> np.ndarray:
    """The lidar2ego of a scene's original log (its first frame's: constant over a log, one vehicle and one rig),
    read once per worker and log."""
    return lidar2ego(load_log(Path(log_path))[0], f"{log_path} frame 0")


class SyntheticScene:
    """One loaded synthetic scene: history poses in the current ego frame, then the sample fields."""

    def __init__(self, source: SceneSource, log: LogRef) -> None:
        self.source, self.log, self.path = source, log, Path(log.path)
        self.scene = load_scene(self.path)
        self.metadata = self.scene["scene_metadata"]
        self.frames = self.scene["frames"]
        self.where = f"{self.path}"
        self.current = int(self.metadata.get("num_history_frames", len(self.frames))) - 1
        if not 0 <= self.current < len(self.frames):
            raise NavsimFormatError(f"{self.path}: num_history_frames does not fit its {len(self.frames)} frames")
        self.poses = np.array([self._status(i)["ego_pose"] for i in range(len(self.frames))], np.float64)
        self.stamps = np.array([int(f["timestamp"]) for f in self.frames], np.int64)
        self.origin = self.poses[self.current]

    def _status(self, index: int) -> dict[str, np.ndarray]:
        status = required(self.frames[index], "ego_status", f"{self.where} frame {index}")
        out = {}
        for name, size in (("ego_pose", 3), ("ego_velocity", 2), ("ego_acceleration", 2), ("driving_command", 4)):
            value = np.asarray(status.get(name), np.float64).ravel() if name in status else None
            if value is None or value.shape != (size,) or not np.isfinite(value).all():
                raise NavsimFormatError(f"{self.where} frame {index}: ego_status.{name} must be {size} finite numbers")
            out[name] = value
        return out

    def sample(self) -> dict[str, Any]:
        source, frame = self.source, self.frames[self.current]
        token = str(self.metadata.get("initial_token") or frame["token"])
        log_name = str(self.metadata["log_name"])
        t = ((self.stamps - self.stamps[self.current]) / 1e6).astype(np.float32)
        past = np.column_stack([t, to_local(self.poses, self.origin)]).astype(np.float32)[: self.current + 1]
        lidar2ego = lidar2ego_of(str(Path(self.log.extra["logs"]) / f"{log_name}.pkl"))
        sample: dict[str, Any] = {"__key__": make_key(log_name, token), "past": past}
        cameras = self.cameras(frame, lidar2ego, sample)
        now = self.annotations(frame, lidar2ego)
        sample["boxes"] = now["boxes"]
        sample["agents_future"] = self.agents_future(now)
        map_name = navsim_map.resolve_location(str(self.metadata["map_name"]))
        roadblocks = [str(r) for r in frame.get("roadblock_ids", [])]
        if source.maps is not None:
            red = [[int(lc) for lc, is_red in frame.get("traffic_lights", []) if is_red]]
            red += [
                red_lights(s, f"{self.where} extended_traffic_light_data[{k}]")
                for k, s in enumerate(self.scene["extended_traffic_light_data"] or [])
            ]
            times = np.arange(len(red)) * 0.5
            add_map_fields(source, sample, map_name, self.origin, roadblocks, red, times, self.ego_past(), self.where)
        extras = {
            "scene_token": token,
            "initial_token": token,
            "log_name": log_name,
            "map_location": str(self.metadata["map_name"]),
            "map_name": map_name,
            "data_split": self.log.split,
            "roadblock_ids": roadblocks,
            "traffic_lights": [[int(lc), bool(red)] for lc, red in frame.get("traffic_lights", [])],
            "track_tokens": now["tracks"],
            "box_names": now["names"],
            "corresponding_original_scene": self.metadata.get("corresponding_original_scene"),
            "corresponding_original_initial_token": self.metadata.get("corresponding_original_initial_token"),
        } | source.two_stage_extras(token)
        status = self._status(self.current)
        velocity, acceleration = status["ego_velocity"].tolist(), status["ego_acceleration"].tolist()
        previous = past[-2] if len(past) > 1 else past[-1]
        ego = ego_meta(velocity, acceleration, status["driving_command"], previous)
        scene = SceneFrame(self.log, log_name, self.current, int(self.stamps[self.current]), True)
        sample["meta"] = scene_meta(source, scene, extras, ego, cameras, sample)
        return sample

    def cameras(self, frame: dict, lidar2ego: np.ndarray, sample: dict) -> list[dict[str, Any]]:
        """The current frame's cameras (``camera_dict`` keys ``cam_f0`` ...; a camera without an image is ``{}``)."""
        cameras = []
        camera_dict = frame.get("camera_dict") or {}
        sensors = Path(self.log.extra["sensors"])
        for native, cam_id in CAMERAS.items():
            cam = camera_dict.get(native.lower()) or {}
            if not cam.get("data_path"):
                continue
            where = f"{self.where} camera_dict.{native.lower()}"
            sample[f"cam_{cam_id}"], entry = read_camera(cam, native, cam_id, sensors, lidar2ego, where)
            cameras.append(entry)
        return cameras

    def annotations(self, frame: dict, lidar2ego: np.ndarray) -> dict[str, Any]:
        """The current frame's boxes (N, 10) as the logs' are converted (velocity rotated by lidar2ego)."""
        where = f"{self.where} frame {self.current} annotations"
        anns = required(frame, "annotations", f"{self.where} frame {self.current}")
        anns = read_annotations(anns, SCENE_ANNOTATIONS, lidar2ego, where)
        return {"boxes": anns["rows"], "names": anns["names"], "tracks": anns["tracks"]}

    def agents_future(self, now: dict[str, Any]) -> dict[str, np.ndarray]:
        """Every track of ``extended_detections_tracks`` (2 Hz after the current frame) in the current ego frame
        (:func:`~navsim_scene.agents_future`, the layout of the logs' ``agents_future``)."""
        steps = [
            tracked_objects(d, f"{self.where} extended_detections_tracks[{k}]")
            for k, d in enumerate(self.scene["extended_detections_tracks"] or [])
        ]
        t = np.arange(1, len(steps) + 1) * 0.5
        return agents_future(now["tracks"], now["boxes"][:, 3:6], now["boxes"][:, 9], steps, t, self.origin)

    def ego_past(self) -> np.ndarray:
        """The history frames (:func:`~navsim_scene.ego_past`), from each frame's ``ego_status``."""
        index = np.arange(self.current + 1)
        dynamics = [np.r_[self._status(i)["ego_velocity"], self._status(i)["ego_acceleration"]] for i in index]
        now_us = int(self.stamps[self.current])
        return ego_past(self.stamps[index], self.poses[index], np.array(dynamics), self.origin, now_us)
