"""OpenScene log pickle -> schema v1 samples: one per NAVSIM scene (``num_history_frames`` frames whose last is the
current frame, plus ``num_future_frames``). nuPlan data is already ISO 8855 with the origin at the rear axle, so
nothing is flipped. Layout of every field: ``docs/datasets/navsim.md``."""

from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.geometry import to_global, to_local
from lead_s2r.registry import LogRef
from lead_s2r.schema import make_key
from lead_s2r_adapters import navsim_map
from lead_s2r_adapters.navsim_io import (
    CAMERAS,
    LOG_ANNOTATIONS,
    NavsimFormatError,
    lidar2ego,
    quaternion_yaw,
    read_annotations,
    read_camera,
    read_pcd,
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


class LogScenes:
    """One loaded log: global ego poses once, then a sample per scene."""

    def __init__(self, source: SceneSource, log: LogRef, frames: list[dict[str, Any]]) -> None:
        self.source, self.log, self.frames = source, log, frames
        self.path = Path(log.path)
        self.sensors = Path(log.extra["sensors"])
        poses, stamps = [], []
        for i, frame in enumerate(frames):
            where = self.where(i)
            translation = np.asarray(required(frame, "ego2global_translation", where), np.float64)
            yaw = quaternion_yaw(required(frame, "ego2global_rotation", where))
            poses.append([translation[0], translation[1], yaw])
            stamps.append(int(required(frame, "timestamp", where)))
        self.poses = np.array(poses)
        self._annotations: dict[int, dict[str, Any]] = {}
        self.stamps = np.array(stamps, np.int64)
        if (np.diff(self.stamps) <= 0).any():
            raise NavsimFormatError(f"{self.path}: field 'timestamp' is not strictly increasing")

    def where(self, index: int) -> str:
        return f"{self.path} frame {index}"

    def sample(self, start: int, current: int) -> dict[str, Any]:
        """The sample of the scene whose first frame is ``start`` and current frame ``current``."""
        source, frame, where = self.source, self.frames[current], self.where(current)
        origin = self.poses[current]
        index = np.arange(start, current + source.future + 1)
        t = ((self.stamps[index] - self.stamps[current]) / 1e6).astype(np.float32)
        trajectory = np.column_stack([t, to_local(self.poses[index], origin)]).astype(np.float32)
        to_ego = lidar2ego(frame, where)
        token = required(frame, "token", where, str)
        location = required(frame, "map_location", where, str)
        sample: dict[str, Any] = {
            "__key__": make_key(self.log.log_id, token),
            "past": trajectory[: source.history],
            "future": trajectory[source.history :],
        }
        cameras = self.cameras(frame, where, to_ego, sample)
        points, columns = read_pcd(self.sensors / required(frame, "lidar_path", where, str))
        points[:, :3] = (points[:, :3].astype(np.float64) @ to_ego[:3, :3].T + to_ego[:3, 3]).astype(np.float32)
        sample["lidar"] = points
        extras: dict[str, Any] = {
            "scene_token": token,
            "initial_token": str(self.frames[start].get("token")),
            "log_name": str(frame.get("log_name", self.log.log_id)),
            "map_location": location,
            "map_name": navsim_map.resolve_location(location),
            "data_split": self.log.split,
            "roadblock_ids": [str(r) for r in required(frame, "roadblock_ids", where)],
            "traffic_lights": [[int(lc), bool(red)] for lc, red in required(frame, "traffic_lights", where)],
        } | source.two_stage_extras(token)
        if "anns" in frame:
            now = self.annotations(current)
            sample["boxes"] = now["rows"]
            sample["agents_future"] = self.agents_future(current, now)
            extras.update(track_tokens=now["tracks"], box_names=now["names"])
        if source.maps is not None:
            future = range(current, current + source.future + 1)
            red = [[int(lc) for lc, is_red in self.traffic_lights(i) if is_red] for i in future]
            times = (self.stamps[list(future)] - self.stamps[current]) / 1e6
            roadblocks, map_name = extras["roadblock_ids"], extras["map_name"]
            add_map_fields(source, sample, map_name, origin, roadblocks, red, times, self.ego_past(current), where)
        ego = self.ego(current, where, trajectory[source.history - 2])
        scene = SceneFrame(self.log, self.log.log_id, current, int(self.stamps[current]), False)
        sample["meta"] = scene_meta(source, scene, extras, ego, cameras, sample) | {"lidar_columns": columns}
        return sample

    def ego(self, current: int, where: str, previous: np.ndarray) -> dict[str, Any]:
        """``meta.ego`` of frame ``current``; ``previous`` is the pose before it, [t < 0, x, y, yaw] in its frame."""
        state = self.dynamic_state(current).tolist()
        one_hot = np.asarray(required(self.frames[current], "driving_command", where)).ravel()
        if one_hot.shape != (4,):
            raise NavsimFormatError(f"{where}: field 'driving_command' must be a (4,) one-hot, got {one_hot!r}")
        return ego_meta(state[:2], state[2:], one_hot, previous)

    def dynamic_state(self, index: int) -> np.ndarray:
        """Frame ``index``'s ``ego_dynamic_state``: vx, vy, ax, ay in the body frame."""
        state = np.asarray(required(self.frames[index], "ego_dynamic_state", self.where(index)), np.float64).ravel()
        if state.shape != (4,) or not np.isfinite(state).all():
            problem = f"field 'ego_dynamic_state' must be 4 finite numbers, got {state.tolist()!r}"
            raise NavsimFormatError(f"{self.where(index)}: {problem}")
        return state

    def cameras(self, frame: dict, where: str, lidar2ego: np.ndarray, sample: dict) -> list[dict[str, Any]]:
        cameras = []
        for native, cam_id in CAMERAS.items():
            cam = required(required(frame, "cams", where), native, where)
            sample[f"cam_{cam_id}"], entry = read_camera(
                cam, native, cam_id, self.sensors, lidar2ego, f"{where} cams.{native}"
            )
            cameras.append(entry)
        return cameras

    def traffic_lights(self, index: int) -> list:
        return required(self.frames[index], "traffic_lights", self.where(index))

    def annotations(self, index: int) -> dict[str, Any]:
        """A frame's ``anns`` as arrays, with classes mapped; boxes (N, 7) in that frame's ego frame, and as the
        ``step`` of the scenes it is a future frame of (global poses, velocities in its ego frame). Cached: with a
        stride of 1 every frame is a future frame of up to ``num_future_frames`` scenes."""
        if index not in self._annotations:
            frame, where = self.frames[index], self.where(index)
            anns = required(frame, "anns", where)
            anns = read_annotations(anns, LOG_ANNOTATIONS, lidar2ego(frame, where), f"{where} anns")
            poses = to_global(anns["boxes"][:, [0, 1, 6]], self.poses[index])
            size = anns["boxes"][:, 3:6]
            step = TrackStep(anns["tracks"], poses, anns["velocity"], self.poses[index, 2], size, anns["classes"])
            self._annotations[index] = anns | {"step": step}
        return self._annotations[index]

    def agents_future(self, current: int, now: dict[str, Any]) -> dict[str, np.ndarray]:
        """The other agents' tracks over the scene's future frames (:func:`~navsim_scene.agents_future`)."""
        index = np.arange(current + 1, current + 1 + self.source.future)
        steps = [self.annotations(i)["step"] for i in index]
        t = (self.stamps[index] - self.stamps[current]) / 1e6
        return agents_future(now["tracks"], now["boxes"][:, 3:6], now["classes"], steps, t, self.poses[current])

    def ego_past(self, current: int) -> np.ndarray:
        """The history frames up to and including ``current`` (:func:`~navsim_scene.ego_past`), from each frame's
        ``ego_dynamic_state``."""
        index = np.arange(current - self.source.history + 1, current + 1)
        dynamics = np.array([self.dynamic_state(i) for i in index])
        origin, now_us = self.poses[current], int(self.stamps[current])
        return ego_past(self.stamps[index], self.poses[index], dynamics, origin, now_us)
