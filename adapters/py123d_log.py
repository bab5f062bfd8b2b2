"""One 123D log's modalities in our rear-axle frame: ego poses and dynamics, boxes and their tracks, pinhole
cameras, LiDAR and traffic lights, each looked up per sync iteration (the frame layout: ``py123d_frames``).

Reading is per log and lazy per modality: the ego and box files are read once (every sample's past, future and
agents' futures come from them), camera and LiDAR files are memory-mapped and only the rows a sample uses are
decoded. JPEG bytes leave exactly as stored.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.geometry import to_local, wrap_angle
from lead_s2r_adapters.navsim_scene import TrackStep, agents_future
from lead_s2r_adapters.py123d_arrow import (
    BOX_KEY,
    EGO_KEY,
    LIGHT_KEY,
    SYNC_FILE,
    LogFiles,
    Py123dFormatError,
    column,
    decode_points,
    fixed_rows,
    meta_pose,
)
from lead_s2r_adapters.py123d_frames import MAX_COORDINATE, pose_matrix, rear_axle_poses, to_rear_axle, vehicle
from lead_s2r_adapters.py123d_labels import box_class

#: py123d's CameraID names -> our ``cam_<id>`` (L0/R0 are the front-most side cameras, L2/R2 the rear-most).
CAMERA_IDS = {
    "pcam_f0": "front",
    "pcam_b0": "back",
    "pcam_l0": "front_left",
    "pcam_l1": "left",
    "pcam_l2": "back_left",
    "pcam_r0": "front_right",
    "pcam_r1": "right",
    "pcam_r2": "back_right",
    "pcam_stereo_l": "stereo_left",
    "pcam_stereo_r": "stereo_right",
}


def camera_id(key: str) -> str:
    """Our camera id of a py123d camera modality key (``camera.pcam_f0`` -> ``front``)."""
    native = key.partition(".")[2]
    return CAMERA_IDS.get(native, native)


#: m/s no ego reaches (the fastest road cars: about 140)
MAX_SPEED = 200.0
LIGHT_STATUS = ("GREEN", "YELLOW", "RED", "OFF", "UNKNOWN")
RED = 2


@dataclass
class Boxes:
    """One iteration's boxes in the current ego frame, plus what identifies them."""

    rows: np.ndarray  # (N, 10) float64, our box layout
    tokens: list[str]
    raw_labels: list[str | None]


class LogData:
    """The ego, boxes and sensors of one log (``files``), addressed by sync iteration."""

    def __init__(self, files: LogFiles) -> None:
        self.files = files
        if not files.has(EGO_KEY):
            raise Py123dFormatError(files.folder, f"no {EGO_KEY}.arrow: a 123D log without ego states has no samples")
        table, self.ego_meta = files.table(EGO_KEY)
        path = files.path(EGO_KEY)
        self.rear_axle_to_imu = meta_pose(self.ego_meta, path, "rear_axle_to_imu_se3")
        centre_to_imu = meta_pose(self.ego_meta, path, "center_to_imu_se3")
        try:
            self.vehicle = vehicle(self.ego_meta, centre_to_imu, self.rear_axle_to_imu)
        except (KeyError, TypeError, ValueError):
            raise Py123dFormatError(path, "ego metadata lacks the vehicle size", "metadata") from None
        imu = fixed_rows(table, path, f"{EGO_KEY}.imu_se3", 7)
        name = f"{EGO_KEY}.dynamic_state_se3"
        self.ego_dynamics = fixed_rows(table, path, name, 9) if name in table.column_names else None
        rows = files.sync[EGO_KEY]
        self.valid = rows >= 0  # an iteration without an ego state has no sample
        self.ego_rows = np.where(self.valid, rows, 0)
        with np.errstate(divide="ignore", invalid="ignore"):  # a zero quaternion: NaN, refused below
            self.world = rear_axle_poses(imu[self.ego_rows], self.rear_axle_to_imu)  # (I, 4, 4) per iteration
        near = (np.abs(self.world[:, :3, 3]) < MAX_COORDINATE).all(axis=1)
        broken = self.valid & ~(np.isfinite(self.world).all(axis=(1, 2)) & near)
        if broken.any():  # dropping the iteration would lose its sample without a word
            problem = f"row {self.ego_rows[broken][0]}: the pose is null, not finite, {MAX_COORDINATE:g} m or more away"
            problem += " or has a zero quaternion"
            raise Py123dFormatError(path, problem, f"{EGO_KEY}.imu_se3")
        self.pose2d = np.column_stack([self.world[:, :2, 3], np.arctan2(self.world[:, 1, 0], self.world[:, 0, 0])])
        self.t_us = files.timestamps_us
        self._check_speed(path)
        self._box_cache: dict[int, tuple | None] = {}
        self._light_cache: dict[int, list[tuple[int, int]]] = {}

    def _check_speed(self, path: Path) -> None:
        """A pose the ego cannot have reached from the one before is damaged: one flipped exponent bit moves it by
        1e9 m, and the route built along the driven path (a point a metre) would fill the memory."""
        valid = np.flatnonzero(self.valid)
        moved = np.hypot(*np.diff(self.pose2d[valid, :2], axis=0).T)
        fast = moved > MAX_SPEED * np.diff(self.t_us[valid]) / 1e6
        if fast.any():
            k = int(np.argmax(fast))
            problem = f"row {self.ego_rows[valid[k + 1]]}: the ego moved {moved[k]:.3g} m since the iteration before"
            raise Py123dFormatError(path, f"{problem}, faster than {MAX_SPEED:g} m/s", f"{EGO_KEY}.imu_se3")

    def trajectory(self, i: int, span: np.ndarray) -> np.ndarray:
        """[t, x, y, yaw] of iterations ``span`` in the frame of iteration ``i``."""
        span = span[self.valid[span]]
        local = to_local(self.pose2d[span], self.pose2d[i])
        t = (self.t_us[span] - self.t_us[i]) / 1e6
        return np.column_stack([t, local[:, :2], wrap_angle(local[:, 2])]).astype(np.float32)

    def dynamics(self, i: int) -> np.ndarray | None:
        """(9,) body-frame velocity, acceleration and angular velocity as stored, None where the log has none."""
        if self.ego_dynamics is None:
            return None
        row = self.ego_dynamics[self.ego_rows[i]]
        return row if np.isfinite(row).all() else None

    def boxes_in(self, j: int, i: int) -> Boxes | None:
        """Boxes observed at iteration ``j``, in the ego frame of iteration ``i`` (None where the log has no box file
        or row)."""
        world = self._world_boxes(j)
        if world is None:
            return None
        poses, sizes, velocity, classes, tokens, raw = world
        local = np.linalg.inv(self.world[i]) @ poses
        rows = np.zeros((len(tokens), 10))
        rows[:, 0:3] = local[:, :3, 3]
        rows[:, 3:6] = sizes
        rows[:, 6] = np.arctan2(local[:, 1, 0], local[:, 0, 0])
        rows[:, 7:9] = (velocity @ self.world[i][:3, :3])[:, :2]  # world -> ego: R^T v, row-wise
        rows[:, 9] = classes
        return Boxes(rows, tokens, raw)

    def _world_boxes(self, j: int) -> tuple | None:
        """Iteration ``j``'s boxes in the world, decoded once per log: 4x4 poses, sizes, velocities, classes,
        tokens and raw labels (the ego's own box dropped)."""
        if j in self._box_cache:
            return self._box_cache[j]
        if not self.files.has(BOX_KEY) or self.files.sync[BOX_KEY][j] < 0:
            self._box_cache[j] = None
            return None
        table, meta = self.files.table(BOX_KEY)
        path, row = self.files.path(BOX_KEY), int(self.files.sync[BOX_KEY][j])
        tokens = [str(t) for t in column(table, path, f"{BOX_KEY}.track_token")[row].as_py() or []]
        velocity = column(table, path, f"{BOX_KEY}.velocity_3d")[row].as_py() or [None] * len(tokens)
        try:  # the column types are checked (LogFiles.table); a null inside a list is not
            boxes = np.asarray(column(table, path, f"{BOX_KEY}.bounding_box_se3")[row].as_py() or [], np.float64)
            labels = [int(label) for label in column(table, path, f"{BOX_KEY}.label")[row].as_py() or []]
            moving = [[np.nan] * 3 if v is None else v for v in velocity]  # null: py123d has no velocity, unknown
            moving = np.asarray(moving, np.float64).reshape(-1, 3)
        except (TypeError, ValueError):
            raise Py123dFormatError(path, f"row {row}: a null inside a list of boxes", "bounding_box_se3") from None
        if boxes.reshape(-1, 10).shape != (len(tokens), 10) or not len(labels) == len(moving) == len(tokens):
            raise Py123dFormatError(path, f"row {row}: boxes, tokens and labels disagree in length", "bounding_box_se3")
        qualified = str(meta.get("box_detection_label_class", "unknown"))
        classes = [box_class(qualified, label) for label in labels]
        keep = [k for k, (cls, _) in enumerate(classes) if cls is not None]
        boxes = boxes.reshape(-1, 10)[keep]
        moving = moving[keep]
        with np.errstate(divide="ignore", invalid="ignore"):  # a zero quaternion: NaN, refused below
            poses = pose_matrix(boxes[:, :7])
        known = ~np.isnan(moving).all(axis=1)  # null (or all NaN): unknown; partly NaN or huge: damage
        near = (np.abs(boxes) < MAX_COORDINATE).all() and (np.abs(moving[known]) < MAX_COORDINATE).all()
        if not (near and np.isfinite(poses).all()):
            problem = f"row {row}: a box value is not finite or {MAX_COORDINATE:g} or more, or a quaternion is zero"
            raise Py123dFormatError(path, problem, "bounding_box_se3")
        self._box_cache[j] = (
            poses,
            boxes[:, 7:10],
            moving,
            np.array([int(classes[k][0]) for k in keep], np.float64),
            [tokens[k] for k in keep],
            [classes[k][1] for k in keep],
        )
        return self._box_cache[j]

    def agents_future(self, i: int, now: Boxes, span: np.ndarray) -> dict[str, np.ndarray]:
        """Tracks seen at iterations ``span`` in the frame of ``i``, laid out as NAVSIM's
        (:func:`~lead_s2r_adapters.navsim_scene.agents_future`)."""
        steps = []
        for j in span:
            later = self.boxes_in(int(j), i)
            rows, tokens = (np.zeros((0, 10)), []) if later is None else (later.rows, later.tokens)
            steps.append(TrackStep(tokens, rows[:, [0, 1, 6]], rows[:, 7:9], 0.0, rows[:, 3:6], rows[:, 9]))
        t = (self.t_us[span] - self.t_us[i]) / 1e6
        return agents_future(now.tokens, now.rows[:, 3:6], now.rows[:, 9], steps, t)

    def cameras(self, i: int) -> tuple[dict[str, bytes], list[dict[str, Any]], dict[str, str]]:
        """JPEG bytes and calibration of every pinhole camera with a JPEG at ``i``; skipped cameras and why."""
        images, calibration, skipped = {}, [], {}
        for key in self.files.keys("camera."):
            _, meta = self.files.table(key)
            native, cam_id = key.partition(".")[2], camera_id(key)
            if meta.get("camera_model") != "pinhole":
                skipped[cam_id] = f"camera model {meta.get('camera_model')!r} (only pinhole cameras are read)"
                continue
            row = int(self.files.sync[key][i])
            if row < 0:
                continue
            data = self.files.value(key, "data", row)  # bytes, or a path (a str) into the source dataset
            if not isinstance(data, bytes) or data[:2] != b"\xff\xd8":
                skipped[cam_id] = "stored as a path, PNG or video frame, not JPEG bytes"
                continue
            images[f"cam_{cam_id}"] = data
            calibration.append(self._calibration(cam_id, native, meta))
        return images, calibration, skipped

    def _calibration(self, cam_id: str, native: str, meta: dict[str, Any]) -> dict[str, Any]:
        path = self.files.path(f"camera.{native}")
        extrinsic = pose_matrix(meta_pose(meta, path, "camera_to_imu_se3"))
        try:
            fx, fy, cx, cy, skew = (float(v) for v in meta["intrinsics"])
            distortion = [float(v) for v in (meta.get("distortion") or [0.0] * 5)]
            width, height = int(meta["width"]), int(meta["height"])
        except (KeyError, TypeError, ValueError):
            raise Py123dFormatError(path, "pinhole metadata lacks intrinsics, extrinsic or size", "metadata") from None
        return {
            "id": cam_id,
            "native_name": str(meta.get("camera_name", native)),
            "width": width,
            "height": height,
            "K": [[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]],
            "distortion": distortion,
            "cam_to_ego": to_rear_axle(extrinsic, self.rear_axle_to_imu).tolist(),
        }

    def lidar(self, i: int, z_offset: float = 0.0) -> tuple[np.ndarray, list[str]] | None:
        """Every LiDAR's points of ``i`` in the rear-axle frame, with their feature columns (NaN where a sensor
        lacks one) and a ``sensor`` column when the log keeps several LiDARs apart; ``z_offset`` is subtracted
        from z as stored (the LEAD correction)."""
        clouds = []
        for key in self.files.keys("lidar."):
            row = int(self.files.sync[key][i])
            if row < 0:
                continue
            data = self.files.value(key, "data", row)
            if not isinstance(data, bytes):
                continue  # stored as a path into the source dataset: not in the log
            xyz, features = decode_points(data, self.files.path(key))
            xyz[:, 2] -= z_offset
            clouds.append((xyz, {k: np.asarray(v, np.float64) for k, v in features.items()}))
        if not clouds:
            return None
        names = sorted({name for _, features in clouds for name in features})
        to_ego = np.linalg.inv(pose_matrix(self.rear_axle_to_imu))
        parts = []
        for index, (xyz, features) in enumerate(clouds):
            points = xyz @ to_ego[:3, :3].T + to_ego[:3, 3]
            extra = [features.get(name, np.full(len(xyz), np.nan)) for name in names]
            sensor = [np.full(len(xyz), float(index))] if len(clouds) > 1 else []
            parts.append(np.column_stack([points, *extra, *sensor]))
        columns = ["x", "y", "z", *names, *(["sensor"] if len(clouds) > 1 else [])]
        return np.concatenate(parts).astype(np.float32), columns

    def lights(self, i: int) -> list[tuple[int, int]]:
        """(lane id, status) of the traffic lights at iteration ``i`` ([] where the log has none), read once."""
        if i not in self._light_cache:
            self._light_cache[i] = []
            if self.files.has(LIGHT_KEY) and self.files.sync[LIGHT_KEY][i] >= 0:
                row = int(self.files.sync[LIGHT_KEY][i])
                lanes = self.files.value(LIGHT_KEY, "lane_id", row) or []
                status = self.files.value(LIGHT_KEY, "status", row) or []
                path = self.files.path(LIGHT_KEY)
                if len(lanes) != len(status):
                    raise Py123dFormatError(path, f"row {row}: lane ids and statuses differ", "status")
                if None in lanes or None in status:  # the column types are checked (LogFiles.table)
                    raise Py123dFormatError(path, f"row {row}: a null lane id or status", "status")
                self._light_cache[i] = [(int(lane), int(s)) for lane, s in zip(lanes, status, strict=True)]
        return self._light_cache[i]


def log_folders(src: Path) -> list[Path]:
    """Folders holding a ``sync.arrow`` or an ego state file under ``src`` (a 123D data root, its ``logs/`` or one
    split), sorted: a log that lost one of the two is still listed, and fails naming the missing file."""
    root = src / "logs" if (src / "logs").is_dir() else src
    return sorted({path.parent for name in (SYNC_FILE, f"{EGO_KEY}.arrow") for path in root.rglob(name)})
