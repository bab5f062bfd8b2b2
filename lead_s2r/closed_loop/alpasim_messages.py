"""AlpaSim's messages in our terms and back: a scene camera as a schema calibration, matched to the model's cameras
by direction and field of view; a session's egomotion, route and images as a schema v1 sample; the model's plan as
AlpaSim's trajectory. Every mistake in a message is a :class:`RequestError` naming its field.
"""

import math
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import grpc
import numpy as np
from carla_driver_interface import protocol
from scipy.spatial.transform import Rotation

from lead_s2r.closed_loop.alpasim_model import CameraSlot, ServedModel
from lead_s2r.data.device_inputs import decode_rgb, jpeg_tensor
from lead_s2r.geometry import homogeneous, to_global, to_local, wrap_angle
from lead_s2r.schema import SCHEMA_VERSION, Command

#: A scene camera serves a model camera whose field of view is within this factor of its own.
FOV_FACTOR = 2.0
#: AlpaSim's driver: the first route waypoint this far ahead gives the command, LEFT / RIGHT beyond this offset.
COMMAND_LOOKAHEAD_M, COMMAND_OFFSET_M = 5.0, 2.0
#: Route target points for models that read them: the first waypoint this far ahead, and the next one this far on.
TARGET_POINT_DISTANCE_M, NEXT_TARGET_POINT_M = 5.0, 25.0
#: Ego poses kept per session for the past trajectory.
HISTORY = 64
#: A pose or route coordinate this far from the origin (m) is damage, not a place (nor 1e8 m: py123d's bound too).
MAX_COORDINATE_M = 1e8
#: A dynamic state value (m/s, m/s^2, rad/s) this large is damage: no vehicle moves, brakes or turns that fast.
MAX_DYNAMICS = 1e3
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
class SceneCamera:
    """One of a session's ``available_cameras`` as a schema camera calibration, with its direction and field of view."""

    logical_id: str
    calibration: dict[str, Any]
    yaw_deg: float
    fov_deg: float


def pose_matrix(pose: Any, name: str) -> np.ndarray:
    """A ``common.Pose`` as a 4x4 matrix; a non-finite value or a zero quaternion is an error naming ``name``."""
    values = np.array([pose.vec.x, pose.vec.y, pose.vec.z, pose.quat.x, pose.quat.y, pose.quat.z, pose.quat.w])
    if not (np.abs(values) < MAX_COORDINATE_M).all() or np.linalg.norm(values[3:]) < 1e-9:  # False for NaN
        raise invalid(f"{name}: not a finite pose {MAX_COORDINATE_M:g} m or less from the origin with a unit "
                      f"quaternion ({values.tolist()})")  # fmt: skip
    return homogeneous(Rotation.from_quat(values[3:]).as_matrix(), values[:3])


def check_dynamics(state: Any, name: str) -> None:
    """A ``DynamicState``'s velocities, accelerations and angular velocity: finite and below :data:`MAX_DYNAMICS`."""
    for part in ("linear_velocity", "linear_acceleration", "angular_velocity", "angular_acceleration"):
        vector = getattr(state, part)
        values = [vector.x, vector.y, vector.z]
        if not all(abs(value) < MAX_DYNAMICS for value in values):  # False for NaN
            raise invalid(f"{name}.{part}: {values} is not finite or {MAX_DYNAMICS:g} or more")


def scene_camera(camera: Any, index: int) -> SceneCamera | None:
    """One ``AvailableCamera`` as a calibration in our schema's terms; None for a camera model other than OpenCV's
    pinhole (f-theta, fisheye: the layout's crop assumes a pinhole), which then serves no model camera."""
    name = f"rollout_spec.vehicle.available_cameras[{index}]"
    intrinsics = camera.intrinsics
    if intrinsics.WhichOneof("camera_param") != "opencv_pinhole_param":
        return None
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


def match_cameras(
    slots: tuple[CameraSlot, ...], cameras: list[SceneCamera], unread: Sequence[str] = ()
) -> dict[str, str]:
    """Scene camera logical id -> model camera id: each model camera gets the scene camera looking nearest its
    direction (within half its field of view; fields of view within :data:`FOV_FACTOR`); else an error naming
    the scene's cameras, ``unread`` ones (not pinhole) among them."""
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
            seen += "".join(f", {logical_id} (not a pinhole camera)" for logical_id in unread)
            raise precondition(
                f"rollout_spec.vehicle.available_cameras: the model reads a {slot.id} camera (looking "
                f"{slot.yaw_deg:.0f} deg, fov {slot.fov_deg:.0f}) and no camera of the scene looks that way with a "
                f"comparable field of view (cameras: {seen})"
            )
        matched[min(candidates)[1]] = slot.id
    return matched


@dataclass
class Session:
    """What one rollout has sent so far; its lock orders the calls of one session."""

    cameras: dict[str, SceneCamera]  # logical id -> camera, of the cameras the model reads
    slot_of: dict[str, str]  # logical id -> model camera id
    images: dict[str, tuple[int, bytes]] = field(default_factory=dict)  # model camera id -> (frame end, JPEG)
    poses: deque = field(default_factory=lambda: deque(maxlen=HISTORY))  # (timestamp_us, 4x4 pose in local)
    dynamics: Any = field(default_factory=protocol.DynamicState)  # the latest (none yet: at rest)
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
    if lateral > COMMAND_OFFSET_M:
        return Command.LEFT
    return Command.RIGHT if lateral < -COMMAND_OFFSET_M else Command.STRAIGHT


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
    velocity = [dynamics.linear_velocity.x, dynamics.linear_velocity.y]
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
    if served.model.reads_target_points:  # a LeadDriver (load_served_model checked the family)
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
            "acceleration": [float(dynamics.linear_acceleration.x), float(dynamics.linear_acceleration.y)],
            "yaw_rate": float(dynamics.angular_velocity.z),
            "command": int(command),
            "command_raw": None,
        },
        "cameras": cameras,
        "has": {name: True for name in sample if name != "__key__"},
        "extras": {},
    }
    return sample


def jpeg_shape(data: bytes) -> tuple[int, int] | None:
    """(rows, columns) of ``data`` decoded as the model's input decodes it (torchvision's libjpeg-turbo, which refuses
    damage OpenCV decodes through); None where ``data`` is no JPEG that decodes."""
    if not data.startswith(b"\xff\xd8"):
        return None
    try:
        image = decode_rgb([jpeg_tensor(data)], "cpu")[0]
    except RuntimeError:
        return None
    return int(image.shape[1]), int(image.shape[2])


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
