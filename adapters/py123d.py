"""123D (py123d) Arrow logs -> schema v1 samples: one log = one ``logs/<split>/<log_name>/`` folder, one sample =
one sync iteration (every ``stride``-th), for every dataset py123d converts and for LEAD's own 123D recordings.

Trajectories keep the log's native rate: ``past`` and ``future`` are the ego's rear-axle poses at every sync
iteration within ``past_s`` / ``future_s`` (a frame is a sample only when its whole future is in the log), and
``agents_future`` follows the box tracks over the same iterations. Frames: ``py123d_frames``; files:
``py123d_arrow``; labels: ``py123d_labels``; maps: ``py123d_map``; LEAD's departures and route planner:
``py123d_lead``. Facts and limits: ``docs/datasets/py123d.md``.
"""

from collections.abc import Iterator
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from lead_s2r.formats.carla_rig import ROAD_OPTION
from lead_s2r.formats.lead_route import RoutePlanner, previous_current_next
from lead_s2r.geometry import points_to_local
from lead_s2r.registry import Adapter, LogRef
from lead_s2r.schema import SCHEMA_VERSION, Command, make_key
from lead_s2r_adapters import navsim_map, py123d_lead, py123d_map
from lead_s2r_adapters.py123d_arrow import ROUTE_KEY, LogFiles, Py123dFormatError, meta_array, meta_pose
from lead_s2r_adapters.py123d_log import LIGHT_STATUS, RED, LogData, camera_id, log_folders

OPTIONAL = ("future", "lidar", "target_points", "route", "boxes", "agents_future", "scoring", "bev_semantic")
LEAD_MODES = ("auto", "yes", "no")
ROUTE_POINTS = 50  # metres of route ahead kept in ``route`` (one point per metre)


class Py123dAdapter(Adapter):
    """Reads a 123D data root (``<src>/logs/<split>/<log>/*.arrow``, maps under ``<src>/maps`` or ``maps``). Options:
    ``split`` overrides the log's own split; ``stride`` keeps every n-th sync iteration as a sample; ``past_s`` /
    ``future_s`` the ego horizons; ``maps`` a 123D maps root (default ``<src>/maps``) and ``map_radius`` the metres of
    map kept per sample (``scoring`` and ``bev_semantic`` only where a map is found); ``lead`` auto | yes | no treats
    logs as LEAD's recordings (auto: recognised by their metadata); ``tp_distance`` / ``plan_spacing`` LEAD's
    route-planner pop distance and sparse-plan spacing."""

    name: ClassVar[str] = "py123d"
    #: 2: LEAD's target points popped exactly as LEAD pops them (formats.lead_route: from the second point, the
    #: look-ahead ending after the point that passes 50 m; every consecutive duplicate merged)
    version: ClassVar[str] = "2"
    extras: ClassVar[str | None] = "py123d"

    def __init__(
        self,
        split: str = "",
        stride: int = 1,
        past_s: float = 2.0,
        future_s: float = 4.0,
        maps: str = "",
        map_radius: float = 50.0,
        lead: str = "auto",
        tp_distance: float = 3.25,
        plan_spacing: float = 50.0,
    ) -> None:
        if stride < 1 or past_s < 0 or future_s <= 0 or map_radius <= 0:
            raise ValueError("stride >= 1, past_s >= 0, future_s > 0 and map_radius > 0 are required")
        if lead not in LEAD_MODES:
            raise ValueError(f"lead must be one of {', '.join(LEAD_MODES)}, got {lead!r}")
        self.split, self.stride, self.past_s, self.future_s = split, stride, float(past_s), float(future_s)
        self.maps, self.map_radius, self.lead = maps, float(map_radius), lead
        self.tp_distance, self.plan_spacing = float(tp_distance), float(plan_spacing)

    def list_logs(self, src: Path) -> list[LogRef]:
        src = Path(src)
        if not src.is_dir():
            raise FileNotFoundError(f"{src}: not a folder of 123D logs")
        maps = Path(self.maps) if self.maps else src / "maps"
        extra = {"maps": str(maps) if maps.is_dir() else ""}
        return [
            LogRef(f"{folder.parent.name}/{folder.name}", self.split or folder.parent.name, str(folder), dict(extra))
            for folder in log_folders(src)
        ]

    def describe(self) -> dict[str, Any]:
        return {
            "dataset": "py123d",
            "frame_rate_hz": "the log's sync rate / stride (LEAD's recordings: 10 Hz)",
            "future": {"rate_hz": "native", "horizon_s": self.future_s},
            "past": {"rate_hz": "native", "horizon_s": self.past_s},
            "stride": self.stride,
            "source_frame": "py123d ISO 8855 world poses of the IMU; converted to the rear axle at t0",
        }

    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        files = LogFiles.open(Path(log.path))
        data = LogData(files)
        lead = self.lead == "yes" or (self.lead == "auto" and py123d_lead.is_lead_log(files.log, data.ego_meta))
        builder = _Builder(self, log, data, lead)
        for i in builder.frames():
            yield builder.sample(int(i))


class _Builder:
    """Turns one log's iterations into samples (the per-log state: rate, route, map and LEAD's planner)."""

    def __init__(self, adapter: Py123dAdapter, log: LogRef, data: LogData, lead: bool) -> None:
        self.adapter, self.log, self.data, self.lead = adapter, log, data, lead
        stamps = data.t_us
        step_s = float(np.median(np.diff(stamps))) / 1e6 if len(stamps) > 1 else 0.1  # they increase (LogFiles)
        self.past_n = round(adapter.past_s / step_s)
        self.future_n = round(adapter.future_s / step_s)
        self.route = self._route()
        maps = log.extra.get("maps")
        path = py123d_map.find_map(data.files.folder, Path(maps) if maps else None, data.files.log)
        self.map = py123d_map.load_map(path) if path is not None else None
        self.targets = self._plan() if lead else None
        self.roadblocks: list[str] = []
        #: every camera field the log may give, so a frame without one says so in ``meta.has``
        self.cameras = [f"cam_{camera_id(key)}" for key in data.files.keys("camera.")]

    def frames(self) -> np.ndarray:
        count = len(self.data.t_us)
        index = np.arange(0, max(count - self.future_n, 0), self.adapter.stride)
        return index[self.data.valid[index]]

    def _route(self) -> np.ndarray | None:
        """The log's route polyline (global x, y every metre) from ``route_position``'s metadata, if written."""
        files = self.data.files
        if not files.has(ROUTE_KEY):
            return None
        _, meta = files.table(ROUTE_KEY)
        if "polyline_x" not in meta or "polyline_y" not in meta:
            return None
        path = files.path(ROUTE_KEY)
        x, y = (meta_array(meta, path, name, (None,)) for name in ("polyline_x", "polyline_y"))
        if len(x) != len(y) or not len(x):
            raise Py123dFormatError(path, f"{len(x)} x but {len(y)} y coordinates", "metadata.polyline_y")
        return np.column_stack([x, y])

    def _plan(self) -> list[tuple[np.ndarray, int]]:
        """LEAD's route planner stepped over every iteration from the log's start, on the centre's driven path:
        (target points in the rear-axle frame, RoadOption)."""
        offset = self.data.vehicle["rear_axle_to_center"]
        poses = self.data.pose2d[self.data.valid]
        route = py123d_lead.centre_path(poses, offset)
        points, options = py123d_lead.sparse_plan(route, py123d_lead.road_options(route), self.adapter.plan_spacing)
        planner = RoutePlanner(points, options, self.adapter.tp_distance)
        route, out = list(planner.route), []
        for pose, valid in zip(self.data.pose2d, self.data.valid, strict=True):
            if valid:  # an iteration without an ego state has no sample and must not move the planner
                route = planner.step(pose[:2] + offset * np.array([np.cos(pose[2]), np.sin(pose[2])]))
            targets, commands = previous_current_next(route)
            out.append((points_to_local(targets, pose).astype(np.float32), commands[0]))
        return out

    def sample(self, i: int) -> dict[str, Any]:
        data, files = self.data, self.data.files
        key = make_key(self.log.log_id, f"{i:06d}")
        past = np.arange(max(i - self.past_n, 0), i + 1)
        future = np.arange(i + 1, i + 1 + self.future_n)
        sample: dict[str, Any] = {"__key__": key, "past": data.trajectory(i, past)}
        if len(future):
            sample["future"] = data.trajectory(i, future)
        extras: dict[str, Any] = {
            "log_name": files.log.get("log_name"),
            "source_dataset": files.log.get("dataset"),
            "written_by": f"py123d {files.log.get('version', '?')}",
        }
        boxes = data.boxes_in(i, i)
        if boxes is not None:
            sample["boxes"] = boxes.rows.astype(np.float32)
            sample["agents_future"] = data.agents_future(i, boxes, future)
            extras["box_tokens"] = boxes.tokens
            extras["box_labels"] = boxes.raw_labels
        images, cameras, skipped = data.cameras(i)
        sample.update(images)
        if skipped:
            extras["cameras_skipped"] = skipped
        lidar = data.lidar(i, self._lidar_z_offset())
        if lidar is not None:
            sample["lidar"] = lidar[0]
        command_raw = -1
        if self.targets is not None:
            sample["target_points"], command_raw = self.targets[i]
        if self.route is not None:
            sample["route"] = self._route_ahead(i)
        lights = data.lights(i)
        if self.lead:
            extras["lead"] = {"traffic_lights": py123d_lead.lights(lights)}
        else:
            extras["traffic_lights"] = [[lane, LIGHT_STATUS[s] if s < len(LIGHT_STATUS) else s] for lane, s in lights]
        if self.map is not None:
            sample["scoring"] = self._scoring(i, past, future)
            sample["bev_semantic"] = navsim_map.bev_semantic_raster(
                sample["scoring"], sample.get("boxes", np.zeros((0, 10)))
            )
        sample["meta"] = self._meta(i, sample, cameras, command_raw, extras, lidar[1] if lidar else None)
        return sample

    def _lidar_z_offset(self) -> float:
        keys = self.data.files.keys("lidar.")
        if not self.lead or not keys:
            return 0.0
        meta, path, name = self.data.files.table(keys[0])[1], self.data.files.path(keys[0]), "lidar_to_imu_se3"
        return py123d_lead.lidar_z_offset(meta_pose(meta, path, name) if name in meta else np.zeros(7))

    def _route_ahead(self, i: int) -> np.ndarray:
        """The route's next :data:`ROUTE_POINTS` metres from the point nearest the ego, in the ego frame."""
        assert self.route is not None
        nearest = int(np.argmin(np.hypot(*(self.route - self.data.pose2d[i, :2]).T)))
        ahead = self.route[nearest : nearest + ROUTE_POINTS]
        return points_to_local(ahead, self.data.pose2d[i]).astype(np.float32)

    def _scoring(self, i: int, past: np.ndarray, future: np.ndarray) -> dict[str, np.ndarray]:
        """The PDMS context: map near the ego, roadblocks along the route (else the driven path), red lights."""
        assert self.map is not None
        data = self.data
        steps = np.r_[i, future]
        red = [[] if self.lead else [lane for lane, s in data.lights(int(j)) if s == RED] for j in steps]
        times = (data.t_us[steps] - data.t_us[i]) / 1e6
        if self.route is None:  # the driven path from here on
            roadblocks = py123d_map.route_roadblocks(self.map, data.pose2d[i:, :2][data.valid[i:]])
        else:  # one route for the whole log
            self.roadblocks = self.roadblocks or py123d_map.route_roadblocks(self.map, self.route)
            roadblocks = self.roadblocks
        context = navsim_map.scoring_context(self.map, data.pose2d[i], self.adapter.map_radius, roadblocks, red, times)
        past = past[data.valid[past]]
        dynamics = [self._dynamics(int(j)) for j in past]
        if len(past) >= 2 and all(d is not None for d in dynamics):
            states = np.array([np.r_[v, a] for v, a, _ in dynamics])  # type: ignore[misc]
            context["ego_past"] = np.column_stack([data.trajectory(i, past).astype(np.float64), states])
        return context

    def _dynamics(self, i: int) -> tuple[np.ndarray, np.ndarray, float] | None:
        """Body-frame velocity, acceleration and yaw rate at ``i`` (LEAD's corrected), None where not logged."""
        stored = self.data.dynamics(i)
        if stored is None:
            return None
        if self.lead:
            return py123d_lead.ego_dynamics(stored, float(self.data.pose2d[i, 2]))
        return stored[0:2], stored[3:5], float(stored[8])

    def _meta(
        self,
        i: int,
        sample: dict[str, Any],
        cameras: list[dict[str, Any]],
        command_raw: int,
        extras: dict[str, Any],
        lidar_columns: list[str] | None,
    ) -> dict[str, Any]:
        files = self.data.files
        dynamics = self._dynamics(i)
        if dynamics is None:  # a log without dynamics: the speed from the neighbouring poses
            velocity, acceleration, yaw_rate = self._finite_difference(i), np.zeros(2), 0.0
            extras["ego_dynamics"] = "finite differences of the poses (the log has no dynamic state)"
        else:
            velocity, acceleration, yaw_rate = dynamics
        command = ROAD_OPTION.get(command_raw, Command.UNKNOWN) if self.lead else Command.UNKNOWN
        out: dict[str, Any] = {
            "schema_version": SCHEMA_VERSION,
            "dataset": "lead123d" if self.lead else f"py123d_{files.log.get('dataset')}",
            "split": self.log.split,
            "log_id": self.log.log_id,
            "frame_idx": i,
            "timestamp_us": int(self.data.t_us[i]),
            "is_synthetic": self.lead or str(files.log.get("dataset", "")).lower() == "carla",
            "location": files.log.get("location"),
            "adapter": self.adapter.name,
            "adapter_version": self.adapter.version,
            "ego": {
                "speed": float(np.hypot(*velocity)),
                "velocity": [float(v) for v in velocity],
                "acceleration": [float(a) for a in acceleration],
                "yaw_rate": float(yaw_rate),
                "command": int(command),
                "command_raw": command_raw,
            },
            "vehicle": dict(self.data.vehicle),
            "cameras": cameras,
            "has": {name: name in sample for name in (*OPTIONAL, *self.cameras)},
            "extras": {"py123d": extras},
        }
        if lidar_columns is not None:
            out["lidar_columns"] = lidar_columns
        if "bev_semantic" in sample:
            out["bev"] = navsim_map.BEV_META
        return out

    def _finite_difference(self, i: int) -> np.ndarray:
        j = min(i + 1, len(self.data.t_us) - 1)
        k = max(j - 1, 0)
        dt = (self.data.t_us[j] - self.data.t_us[k]) / 1e6
        local = points_to_local(self.data.pose2d[j, :2], self.data.pose2d[k])
        return np.asarray(local, np.float64) / dt if dt > 0 else np.zeros(2)
