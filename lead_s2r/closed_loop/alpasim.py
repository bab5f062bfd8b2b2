"""Any run of ours or LEAD checkpoint folder served as AlpaSim's driver: the gRPC service ``egodriver.EgodriverService``
(NVlabs/alpasim ``src/grpc/alpasim_grpc/v0/egodriver.proto``). Usage: ``docs/closed_loop.md``, "AlpaSim".

The protos come from one pinned source, PyPI's ``carla-driver-interface`` (extra ``[alpasim]``), which vendors
AlpaSim's unchanged; gRPC itself (threads, framing, status codes) is ``grpcio``'s. Per session the server keeps what
AlpaSim sends (cameras, egomotion, route) and on ``drive`` turns it into a schema v1 sample of the model's source,
then runs the training transform (:class:`~lead_s2r.data.transforms.SourceTransform`) and the network exactly as
``lead-s2r predict`` does: one preprocessing path, so the service drives the model the way the scores measured it.

- Cameras are matched to the model's camera layout by where they look, never by name (AlpaSim's rigs name cameras
  differently per dataset): each camera the model reads has a direction and horizontal field of view
  (:data:`CAMERA_DIRECTIONS`, or the LEAD rig of a CARLA model); the scene's camera whose optical axis (from
  ``rig_to_camera``, the optical frame in the rig: x right, y down, z forward) is nearest within half that field of
  view, and whose own field of view is within a factor :data:`FOV_FACTOR`, fills it. Intrinsics and pose become the
  sample's calibration, so the layout crops the rows the model was trained on. Images stay the JPEG bytes AlpaSim
  sent (the training data was JPEG too).
- Egomotion (poses in AlpaSim's ``local`` frame, dynamic states in the rig frame) gives speed, acceleration and the
  past poses in the current rig frame; the route (rig frame at its timestamp) gives the command as AlpaSim's own
  driver derives it (the lateral offset of the first waypoint :data:`COMMAND_LOOKAHEAD_M` ahead) and, for models
  that read them, route target points.
- The answer is the model's waypoints on its output grid, timestamped ``time_now_us + t``, expressed as AlpaSim's
  own driver and runtime expect: in the ``local`` frame, anchored at the latest ego pose and led by it (the model
  plans in the rig frame: x forward, y left, origin at the rear axle, the ISO frame of our data).

Every mistake of a client is a gRPC status whose one message names the field (INVALID_ARGUMENT, NOT_FOUND,
FAILED_PRECONDITION); it ends that call only, every other session goes on. ``get_version`` sends the revision of the
camera convention it speaks (AlpaSim's) as carla-driver-interface's metadata, so that package's clients agree.
"""

import logging
import math
import threading
from collections import deque
from collections.abc import Callable
from concurrent import futures
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import cv2
import grpc
import numpy as np
import torch
import yaml
from scipy.spatial.transform import Rotation
from torch import nn

from lead_s2r import __version__
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
from lead_s2r.geometry import to_global, to_local, wrap_angle
from lead_s2r.models.input_spec import InputSpec
from lead_s2r.models.lead_config import LeadConfig, TargetDataset
from lead_s2r.schema import SCHEMA_VERSION, Command

try:
    from carla_driver_interface import contract, protocol
except ImportError as err:  # pragma: no cover - depends on the environment
    raise UserError("serving AlpaSim needs its protos and gRPC: pip install 'lead-s2r[alpasim]'") from err

logger = logging.getLogger(__name__)

#: The camera convention spoken: ``rig_to_camera`` is the optical frame in the rig, as AlpaSim's renderers declare it.
CONTRACT_REVISION = 2
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
#: A scene camera serves a model camera whose field of view is within this factor of its own.
FOV_FACTOR = 2.0
#: LEAD's cameras of a target, in its ``used_cameras`` order (a LEAD folder names no data cameras).
LEAD_CAMERAS = {
    TargetDataset.NAVSIM_4CAMERAS: ("front_left", "front", "front_right", "back"),
    TargetDataset.WAYMO_E2E_2025_3CAMERAS: ("front_left", "front", "front_right"),
}
#: AlpaSim's driver: the first route waypoint this far ahead gives the command, LEFT / RIGHT beyond this offset.
COMMAND_LOOKAHEAD_M, COMMAND_OFFSET_M = 5.0, 2.0
#: Route target points for models that read them: the first waypoint this far ahead, and the next one this far on.
TARGET_POINT_DISTANCE_M, NEXT_TARGET_POINT_M = 5.0, 25.0
#: Ego poses kept per session for the past trajectory.
HISTORY = 64
DATASET = "alpasim"


class RequestError(Exception):
    """A client's mistake: the gRPC status code and one message naming the field."""

    def __init__(self, code: grpc.StatusCode, message: str) -> None:
        super().__init__(message)
        self.code = code


def invalid(message: str) -> RequestError:
    return RequestError(grpc.StatusCode.INVALID_ARGUMENT, message)


def precondition(message: str) -> RequestError:
    return RequestError(grpc.StatusCode.FAILED_PRECONDITION, message)


@dataclass(frozen=True)
class CameraSlot:
    """One camera the model reads: its sample field id, direction (degrees, ISO) and horizontal field of view."""

    id: str
    yaw_deg: float
    fov_deg: float


@dataclass(frozen=True)
class SceneCamera:
    """One of a session's ``available_cameras`` as a schema camera calibration, with its direction and field of view."""

    logical_id: str
    calibration: dict[str, Any]
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
    reads_target_points: bool = field(init=False)

    def __post_init__(self) -> None:
        self.transform = SourceTransform(self.source, self.spec, cameras=[slot.id for slot in self.slots])
        self.reads_target_points = bool(getattr(self.model, "reads_target_points", False))

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
    slots = camera_slots(model, model.config, spec, source, found)
    return ServedModel(model, source, spec, slots, torch.device(device), found)


def camera_slots(model: nn.Module, config: Any, spec: InputSpec, source: str, found: Path) -> tuple[CameraSlot, ...]:
    """The model's cameras left to right: a CARLA model's LEAD rig tiles; for other sources the data cameras of its
    run (``config.yaml``), or LEAD's cameras of its target (a LEAD folder), by their nominal directions."""
    if source == "carla":
        return tuple(CameraSlot(c.name, -c.yaw_deg, c.fov_deg) for c in CAMERA_RIGS[rig_for(spec)])
    ids = run_cameras(found, source) if not (found / LEAD_CONFIG_NAME).is_file() else None
    if ids is None and isinstance(config, LeadConfig) and config.target_dataset in LEAD_CAMERAS:
        ids = [c for c, used in zip(LEAD_CAMERAS[config.target_dataset], config.used_cameras, strict=True) if used]
    if not ids:
        raise UserError(f"{found}: no camera list for source {source!r} (data.predict/train.{source}.cameras in the "
                        f"run's config.yaml); pass the run folder of `lead-s2r fit`")  # fmt: skip
    unknown = [c for c in ids if c not in CAMERA_DIRECTIONS and c != "carla_mosaic"]
    if unknown or "carla_mosaic" in ids:
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


# ---------------------------------------------------------------------------------------------------- cameras


def pose_matrix(pose: Any, name: str) -> np.ndarray:
    """A ``common.Pose`` as a 4x4 matrix; a non-finite value or a zero quaternion is an error naming ``name``."""
    values = np.array([pose.vec.x, pose.vec.y, pose.vec.z, pose.quat.x, pose.quat.y, pose.quat.z, pose.quat.w])
    if not np.isfinite(values).all() or np.linalg.norm(values[3:]) < 1e-9:
        raise invalid(f"{name}: not a finite pose with a unit quaternion ({values.tolist()})")
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat(values[3:]).as_matrix()
    matrix[:3, 3] = values[:3]
    return matrix


def scene_camera(camera: Any, index: int) -> SceneCamera:
    """One ``AvailableCamera`` (pinhole intrinsics) as a calibration in our schema's terms."""
    name = f"rollout_spec.vehicle.available_cameras[{index}]"
    intrinsics = camera.intrinsics
    if intrinsics.WhichOneof("camera_param") != "opencv_pinhole_param":
        raise invalid(f"{name}.intrinsics: {intrinsics.WhichOneof('camera_param')} cameras are not supported; "
                      "declare an opencv_pinhole_param (rectified) camera")  # fmt: skip
    pinhole = intrinsics.opencv_pinhole_param
    width, height = intrinsics.resolution_w, intrinsics.resolution_h
    focal = (pinhole.focal_length_x, pinhole.focal_length_y)
    if width <= 0 or height <= 0 or min(focal) <= 0 or not np.isfinite([*focal]).all():
        raise invalid(f"{name}.intrinsics: resolution {width}x{height} and focal lengths {focal} must be positive")
    cam_to_ego = pose_matrix(camera.rig_to_camera, f"{name}.rig_to_camera")
    axis = cam_to_ego[:3, 2]  # the optical axis (camera z) in the rig
    calibration = {
        "id": "",
        "native_name": camera.logical_id,
        "width": int(width),
        "height": int(height),
        "K": [[focal[0], 0.0, pinhole.principal_point_x], [0.0, focal[1], pinhole.principal_point_y], [0, 0, 1.0]],
        "distortion": [*pinhole.radial_coeffs[:2], *pinhole.tangential_coeffs[:2], *pinhole.radial_coeffs[2:3]],
        "cam_to_ego": cam_to_ego.tolist(),
    }
    yaw = math.degrees(math.atan2(axis[1], axis[0]))
    fov = math.degrees(2 * math.atan(width / (2 * focal[0])))
    return SceneCamera(camera.logical_id, calibration, yaw, fov)


def match_cameras(slots: tuple[CameraSlot, ...], cameras: list[SceneCamera]) -> dict[str, str]:
    """Scene camera logical id -> model camera id: each model camera gets the scene camera looking nearest its
    direction (within half its field of view; fields of view within :data:`FOV_FACTOR`); else an error."""
    matched: dict[str, str] = {}
    for slot in slots:
        candidates = [
            (abs(float(wrap_angle(math.radians(c.yaw_deg - slot.yaw_deg)))), c.logical_id)
            for c in cameras
            if c.logical_id not in matched
            and abs(float(wrap_angle(math.radians(c.yaw_deg - slot.yaw_deg)))) <= math.radians(slot.fov_deg / 2)
            and 1 / FOV_FACTOR <= c.fov_deg / slot.fov_deg <= FOV_FACTOR
        ]
        if not candidates:
            seen = ", ".join(f"{c.logical_id} ({c.yaw_deg:.0f} deg, fov {c.fov_deg:.0f})" for c in cameras) or "none"
            raise precondition(
                f"rollout_spec.vehicle.available_cameras: the model reads a {slot.id} camera (looking "
                f"{slot.yaw_deg:.0f} deg, fov {slot.fov_deg:.0f}) and no camera of the scene looks that way with a "
                f"comparable field of view (cameras: {seen})"
            )
        matched[min(candidates)[1]] = slot.id
    return matched


# ---------------------------------------------------------------------------------------------------- sessions


@dataclass
class Session:
    """What one rollout has sent so far; its lock orders the calls of one session."""

    cameras: dict[str, SceneCamera]  # logical id -> camera, of the cameras the model reads
    slot_of: dict[str, str]  # logical id -> model camera id
    images: dict[str, tuple[int, bytes]] = field(default_factory=dict)  # model camera id -> (frame end, JPEG)
    poses: deque = field(default_factory=lambda: deque(maxlen=HISTORY))  # (timestamp_us, 4x4 pose in local)
    dynamics: Any = None  # the latest DynamicState
    route: tuple[int, np.ndarray] | None = None  # (timestamp_us, (K, 2) in the rig frame at that time)
    last_drive_us: int = -(2**63)
    drives: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    def pose_at(self, timestamp_us: int) -> np.ndarray:
        """The ego pose (4x4, local) received nearest to ``timestamp_us``."""
        return min(self.poses, key=lambda entry: abs(entry[0] - timestamp_us))[1]


def planar(matrix: np.ndarray) -> np.ndarray:
    """x, y, yaw of a 4x4 pose."""
    return np.array([matrix[0, 3], matrix[1, 3], math.atan2(matrix[1, 0], matrix[0, 0])])


def route_command(route: np.ndarray) -> Command:
    """AlpaSim's driver's rule: the lateral offset of the first waypoint :data:`COMMAND_LOOKAHEAD_M` ahead."""
    if len(route) == 0:
        return Command.UNKNOWN
    ahead = np.flatnonzero(np.hypot(route[:, 0], route[:, 1]) >= COMMAND_LOOKAHEAD_M)
    if len(ahead) == 0:
        return Command.STRAIGHT
    lateral = route[ahead[0], 1]
    return (
        Command.LEFT
        if lateral > COMMAND_OFFSET_M
        else Command.RIGHT
        if lateral < -COMMAND_OFFSET_M
        else Command.STRAIGHT
    )


def route_target_points(route: np.ndarray) -> np.ndarray:
    """(3, 2) previous (absent: NaN), current and next target point from the route ahead (NaN where it ends)."""
    points = np.full((3, 2), np.nan, np.float32)
    distance = np.hypot(route[:, 0], route[:, 1]) if len(route) else np.zeros(0)
    for row, reach in ((1, TARGET_POINT_DISTANCE_M), (2, NEXT_TARGET_POINT_M)):
        ahead = np.flatnonzero(distance >= reach)
        if len(ahead):
            points[row] = route[ahead[0]]
    return points


def build_sample(session: Session, served: ServedModel, time_now_us: int) -> dict[str, Any]:
    """What the session has received, as a schema v1 sample of the model's source at ``time_now_us``."""
    now_us, now = session.poses[-1]
    current = planar(now)
    history = [(t, planar(pose)) for t, pose in session.poses]
    past = np.array([[(t - now_us) / 1e6, *to_local(p, current)] for t, p in history], np.float32)
    dynamics = session.dynamics
    velocity = [dynamics.linear_velocity.x, dynamics.linear_velocity.y] if dynamics is not None else [0.0, 0.0]
    acceleration = [dynamics.linear_acceleration.x, dynamics.linear_acceleration.y] if dynamics else [0.0, 0.0]
    route = np.zeros((0, 2))
    if session.route is not None:  # the route in the rig frame of its own time, moved to the current one
        route_us, points = session.route
        world = to_global(np.column_stack([points, np.zeros(len(points))]), planar(session.pose_at(route_us)))
        route = to_local(world, current)[:, :2]
    command = route_command(route)
    cameras = []
    sample: dict[str, Any] = {"__key__": f"alpasim_{session.drives:06d}", "past": past}
    for logical_id, camera in session.cameras.items():
        slot = session.slot_of[logical_id]
        cameras.append({**camera.calibration, "id": slot})
        sample[f"cam_{slot}"] = session.images[slot][1]
    if served.reads_target_points:
        sample["target_points"] = route_target_points(route)
    sample["meta"] = {
        "schema_version": SCHEMA_VERSION,
        "dataset": DATASET,
        "split": "closed_loop",
        "log_id": "alpasim",
        "frame_idx": session.drives,
        "timestamp_us": int(time_now_us),
        "is_synthetic": False,
        "location": None,
        "adapter": "alpasim",
        "adapter_version": "1",
        "ego": {
            "speed": float(math.hypot(*velocity)),
            "velocity": [float(v) for v in velocity],
            "acceleration": [float(a) for a in acceleration],
            "yaw_rate": float(dynamics.angular_velocity.z) if dynamics is not None else 0.0,
            "command": int(command),
            "command_raw": None,
        },
        "cameras": cameras,
        "has": {name: True for name in sample if name != "__key__"},
        "extras": {},
    }
    return sample


T = TypeVar("T")


class EgodriverServicer(protocol.EgodriverServiceServicer):
    """``egodriver.EgodriverService`` over one served model, for any number of concurrent sessions."""

    def __init__(self, served: ServedModel) -> None:
        self.served = served
        self.sessions: dict[str, Session] = {}
        self.sessions_lock = threading.Lock()
        self.model_lock = threading.Lock()  # one forward at a time: torch's own threads use every core

    def _call(self, context: grpc.ServicerContext, body: Callable[[], T]) -> T:
        """Run one call; a client's mistake aborts it with its status, anything else with INTERNAL (logged)."""
        try:
            return body()
        except RequestError as err:
            context.abort(err.code, str(err))
        except Exception as err:  # a bug: this call fails, the server and every other session go on
            logger.exception("egodriver call failed")
            context.abort(grpc.StatusCode.INTERNAL, f"{type(err).__name__}: {err}")
        raise AssertionError("unreachable: context.abort raises")

    def session(self, uuid: str) -> Session:
        with self.sessions_lock:
            session = self.sessions.get(uuid)
        if session is None:
            raise RequestError(
                grpc.StatusCode.NOT_FOUND, f"session_uuid {uuid!r}: no such session (start_session first)"
            )
        return session

    def get_version(self, request: Any, context: grpc.ServicerContext) -> Any:
        context.send_initial_metadata(contract.contract_metadata(CONTRACT_REVISION))
        return protocol.VersionId(
            version_id=f"lead-s2r {__version__}: {self.served.path.name} ({self.served.source})",
            git_hash="",
            grpc_api_version=protocol.ALPASIM_API_VERSION,
        )

    def start_session(self, request: Any, context: grpc.ServicerContext) -> Any:
        def body() -> Any:
            if not request.session_uuid:
                raise invalid("session_uuid: empty")
            declared = list(request.rollout_spec.vehicle.available_cameras)
            revision = contract.client_revision(context, CONTRACT_REVISION)
            declared = contract.cameras_to_revision(declared, revision, CONTRACT_REVISION)
            cameras = [scene_camera(camera, index) for index, camera in enumerate(declared)]
            slot_of = match_cameras(self.served.slots, cameras)
            used = {c.logical_id: c for c in cameras if c.logical_id in slot_of}
            with self.sessions_lock:
                if request.session_uuid in self.sessions:
                    raise precondition(f"session_uuid {request.session_uuid!r}: already started")
                self.sessions[request.session_uuid] = Session(used, slot_of)
            return protocol.SessionRequestStatus()

        return self._call(context, body)

    def close_session(self, request: Any, context: grpc.ServicerContext) -> Any:
        def body() -> Any:
            self.session(request.session_uuid)
            with self.sessions_lock:
                self.sessions.pop(request.session_uuid, None)
            return protocol.Empty()

        return self._call(context, body)

    def submit_image_observation(self, request: Any, context: grpc.ServicerContext) -> Any:
        def body() -> Any:
            session, image = self.session(request.session_uuid), request.camera_image
            slot = session.slot_of.get(image.logical_id)
            if slot is None:  # a camera the model does not read (or one the scene never declared)
                return protocol.Empty()
            if not decodable_jpeg(image.image_bytes):
                raise invalid(f"camera_image.image_bytes of camera {image.logical_id!r}: not a decodable JPEG "
                              "(set AlpaSim's image_format: jpeg)")  # fmt: skip
            with session.lock:
                previous = session.images.get(slot, (-(2**63), b""))[0]
                if image.frame_end_us < previous:
                    raise invalid(f"camera_image.frame_end_us of camera {image.logical_id!r}: {image.frame_end_us} "
                                  f"is before the previous frame's {previous}")  # fmt: skip
                session.images[slot] = (image.frame_end_us, bytes(image.image_bytes))
            return protocol.Empty()

        return self._call(context, body)

    def submit_egomotion_observation(self, request: Any, context: grpc.ServicerContext) -> Any:
        def body() -> Any:
            session = self.session(request.session_uuid)
            poses, states = list(request.trajectory.poses), list(request.dynamic_states)
            if states and len(states) != len(poses):
                raise invalid(f"dynamic_states: {len(states)} states for {len(poses)} poses (one per pose)")
            entries = [
                (p.timestamp_us, pose_matrix(p.pose, f"trajectory.poses[{i}].pose")) for i, p in enumerate(poses)
            ]
            with session.lock:
                last = session.poses[-1][0] if session.poses else -(2**63)
                for index, (timestamp, _) in enumerate(entries):
                    if timestamp <= last:
                        raise invalid(f"trajectory.poses[{index}].timestamp_us: {timestamp} is not after the "
                                      f"previous pose's {last}")  # fmt: skip
                    last = timestamp
                session.poses.extend(entries)
                if states:
                    session.dynamics = states[-1]
            return protocol.Empty()

        return self._call(context, body)

    def submit_route(self, request: Any, context: grpc.ServicerContext) -> Any:
        def body() -> Any:
            session = self.session(request.session_uuid)
            points = np.array([[w.x, w.y] for w in request.route.waypoints], np.float64).reshape(-1, 2)
            if not np.isfinite(points).all():
                raise invalid("route.waypoints: not finite")
            with session.lock:
                session.route = (request.route.timestamp_us, points)
            return protocol.Empty()

        return self._call(context, body)

    def submit_recording_ground_truth(self, request: Any, context: grpc.ServicerContext) -> Any:
        """Accepted and unused: the model plans from its sensors, never from the recording."""
        return self._call(context, lambda: (self.session(request.session_uuid), protocol.Empty())[1])

    def drive(self, request: Any, context: grpc.ServicerContext) -> Any:
        def body() -> Any:
            session = self.session(request.session_uuid)
            with session.lock:
                sample, anchor = self.prepare(session, request.time_now_us)
            with self.model_lock:
                plan = self.served.plan(sample)
            return protocol.DriveResponse(trajectory=local_trajectory(plan, self.served.grid_times, anchor,
                                                                      request.time_now_us))  # fmt: skip

        return self._call(context, body)

    def prepare(self, session: Session, time_now_us: int) -> tuple[dict[str, Any], tuple[int, np.ndarray]]:
        """The sample of this step and the anchor pose (timestamp, 4x4 local), after the step's checks."""
        if time_now_us <= session.last_drive_us:
            raise invalid(f"time_now_us: {time_now_us} is not after the previous drive's {session.last_drive_us}")
        if not session.poses:
            raise precondition("drive: no egomotion observation yet (submit_egomotion_observation first)")
        missing = sorted(set(session.slot_of.values()) - set(session.images))
        if missing:
            names = [logical for logical, slot in session.slot_of.items() if slot in missing]
            raise precondition(f"drive: no image yet from cameras {names} (submit_image_observation first)")
        sample = build_sample(session, self.served, time_now_us)
        session.last_drive_us, session.drives = time_now_us, session.drives + 1
        return sample, session.poses[-1]


def decodable_jpeg(data: bytes) -> bool:
    """Whether ``data`` is a JPEG libjpeg decodes (at 1/8 size: a check, not the decode the model's input gets)."""
    if not data.startswith(b"\xff\xd8"):
        return False
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_REDUCED_GRAYSCALE_8) is not None


def local_trajectory(plan: np.ndarray, times: np.ndarray, anchor: tuple[int, np.ndarray], time_now_us: int) -> Any:
    """The rig-frame plan (T, 3) at ``times`` as AlpaSim's driver answers: poses in the local frame, led by the anchor
    (the latest ego pose), timestamped ``time_now_us + t``."""
    _, pose = anchor
    rig = np.vstack([np.zeros((1, 3)), plan])  # the anchor itself leads
    offsets_us = np.r_[0, np.round(np.asarray(times) * 1e6)].astype(np.int64)
    positions = pose[:3, 3] + np.column_stack([rig[:, :2], np.zeros(len(rig))]) @ pose[:3, :3].T
    quats = (Rotation.from_matrix(pose[:3, :3]) * Rotation.from_euler("z", rig[:, 2:3])).as_quat()  # x, y, z, w
    trajectory = protocol.Trajectory()
    for offset_us, position, quat in zip(offsets_us.tolist(), positions.tolist(), quats.tolist(), strict=True):
        entry = trajectory.poses.add(timestamp_us=int(time_now_us) + offset_us)
        entry.pose.vec.x, entry.pose.vec.y, entry.pose.vec.z = position
        entry.pose.quat.x, entry.pose.quat.y, entry.pose.quat.z, entry.pose.quat.w = quat
    return trajectory


def serve(served: ServedModel, host: str, port: int, workers: int = 32) -> tuple[grpc.Server, int]:
    """Start the service on ``host:port`` (0: a free port); the server and the port it listens on."""
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=workers), options=protocol.channel_options())
    protocol.add_EgodriverServiceServicer_to_server(EgodriverServicer(served), server)
    address = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    try:
        bound = server.add_insecure_port(address)
    except RuntimeError as err:
        raise UserError(f"--host/--port {address}: cannot listen there ({err})") from None
    if bound == 0:
        raise UserError(f"--host/--port {address}: cannot listen there (in use, or not an address of this machine)")
    server.start()
    return server, bound
