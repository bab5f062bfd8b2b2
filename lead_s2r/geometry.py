"""SE(2) transforms, CARLA -> ISO 8855 frame conversion, and trajectory resampling.

Poses are arrays ``(..., 3)`` of ``[x, y, yaw]``; points are ``(..., 2)`` or ``(..., 3)`` (z passes through).
CARLA's ego frame is y-right with yaw clockwise and the origin at the vehicle centre; ours is ISO 8855 (y left,
yaw counter-clockwise) with the origin at the rear axle, which lies ``rear_axle_to_center`` metres behind
the centre along x.
"""

import numpy as np

#: CARLA/LEAD rear axle relative to the vehicle centre, metres (``CARLA_REAR_AXLE`` in LEAD).
CARLA_REAR_AXLE_TO_CENTER = 1.389


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Wrap radians into [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def rotate(points: np.ndarray, yaw: np.ndarray | float) -> np.ndarray:
    """Rotate the xy of points (..., 2+) counter-clockwise by ``yaw``; other columns pass through."""
    points = np.asarray(points)
    cos, sin = np.cos(yaw), np.sin(yaw)
    out = points.copy()
    out[..., 0] = cos * points[..., 0] - sin * points[..., 1]
    out[..., 1] = sin * points[..., 0] + cos * points[..., 1]
    return out


def to_local(poses: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Express global poses (..., 3) in the frame of the ``origin`` pose (3,)."""
    poses = np.asarray(poses, dtype=np.float64)
    local = points_to_local(poses, origin)
    local[..., 2] = wrap_angle(poses[..., 2] - float(origin[2]))
    return local


def to_global(poses: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Inverse of :func:`to_local`: poses (..., 3) in the ``origin`` frame back to the global frame."""
    poses = np.asarray(poses, dtype=np.float64)
    origin = np.asarray(origin, dtype=np.float64)
    glob = rotate(poses, origin[2]) + np.r_[origin[:2], 0.0]
    glob[..., 2] = wrap_angle(poses[..., 2] + origin[2])
    return glob


def points_to_local(points: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Express global points (..., 2+) in the frame of the ``origin`` pose; z and further columns pass through."""
    points = np.asarray(points, dtype=np.float64).copy()
    points[..., :2] -= np.asarray(origin, dtype=np.float64)[:2]
    return rotate(points, -float(origin[2]))


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) scalar-first quaternions [w, x, y, z] -> (..., 3, 3) rotation matrices (normalised first); the one
    implementation for every reader of quaternions (NAVSIM's ``lidar2ego_rotation``, py123d's SE3 rows)."""
    q = np.asarray(q, np.float64)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def homogeneous(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """4x4 rigid transform of a 3x3 rotation and a translation (NAVSIM's and WOD's extrinsics, CARLA matrices)."""
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = np.asarray(rotation, np.float64), np.asarray(translation, np.float64)
    return matrix


def box_corners(boxes: np.ndarray) -> np.ndarray:
    """(N, 4, 2) footprint corners of boxes laid out like the schema's ``boxes`` (x, y, z, length, width, height,
    yaw, ...), counter-clockwise from front-left."""
    boxes = np.asarray(boxes, np.float64)
    half = boxes[:, None, 3:5] / 2 * np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]])
    return rotate(half, boxes[:, None, 6]) + boxes[:, None, :2]


def flip_y(values: np.ndarray, columns: tuple[int, ...] = (1,)) -> np.ndarray:
    """Negate the given columns: CARLA (y right, yaw clockwise) <-> ISO (y left, yaw counter-clockwise); its own
    inverse. ``columns=(1,)`` for points and vectors, ``(1, 2)`` for ``[x, y, yaw]`` poses."""
    out = np.array(values, dtype=np.float64, copy=True)
    out[..., list(columns)] = -out[..., list(columns)]
    return out


def centre_points_to_rear_axle(points: np.ndarray, rear_axle_to_center: float) -> np.ndarray:
    """Points (..., 2+) in a centre-origin ego frame -> the same ego's rear-axle frame (x shifted forward)."""
    out = np.array(points, dtype=np.float64, copy=True)
    out[..., 0] += rear_axle_to_center
    return out


def centre_poses_to_rear_axle(poses: np.ndarray, rear_axle_to_center: float) -> np.ndarray:
    """Ego centre poses (..., 3) in the t0 centre frame -> rear-axle poses in the t0 rear-axle frame: each pose's own
    origin moves back along its heading, then the frame origin moves back along x."""
    poses = np.array(poses, dtype=np.float64, copy=True)
    poses[..., 0] -= rear_axle_to_center * np.cos(poses[..., 2])
    poses[..., 1] -= rear_axle_to_center * np.sin(poses[..., 2])
    return centre_points_to_rear_axle(poses, rear_axle_to_center)


def rear_axle_poses_to_centre(poses: np.ndarray, rear_axle_to_center: float) -> np.ndarray:
    """Rear-axle poses (..., 3) in the t0 rear-axle frame -> ego centre poses in the t0 centre frame (the inverse of
    :func:`centre_poses_to_rear_axle`)."""
    poses = np.array(poses, dtype=np.float64, copy=True)
    poses[..., 0] += rear_axle_to_center * np.cos(poses[..., 2]) - rear_axle_to_center
    poses[..., 1] += rear_axle_to_center * np.sin(poses[..., 2])
    return poses


def carla_poses_to_iso(poses: np.ndarray, rear_axle_to_center: float = CARLA_REAR_AXLE_TO_CENTER) -> np.ndarray:
    """CARLA ego-centre poses [x, y, yaw] (t0 centre frame, y right) -> ISO rear-axle poses."""
    return centre_poses_to_rear_axle(flip_y(poses, (1, 2)), rear_axle_to_center)


def carla_points_to_iso(points: np.ndarray, rear_axle_to_center: float = CARLA_REAR_AXLE_TO_CENTER) -> np.ndarray:
    """CARLA ego-centre points (..., 2+) (y right) -> ISO rear-axle points."""
    return centre_points_to_rear_axle(flip_y(points, (1,)), rear_axle_to_center)


def resample(t_source: np.ndarray, values: np.ndarray, t_target: np.ndarray, angle_columns: tuple[int, ...] = ()):
    """Linearly interpolate ``values`` (T, D) from times ``t_source`` to ``t_target``, angle columns unwrapped first
    and wrapped back after. Target times outside the source span are NaN and the returned boolean mask is False
    there: this never extrapolates, and never copies an end point."""
    t_source = np.asarray(t_source, dtype=np.float64)
    t_target = np.asarray(t_target, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2 or len(values) != len(t_source):
        raise ValueError(f"values must be (T, D) with T = len(t_source) = {len(t_source)}, got {values.shape}")
    if len(t_source) > 1 and (np.diff(t_source) <= 0).any():
        raise ValueError("t_source must be strictly increasing")
    eps = 1e-6
    valid = (t_target >= t_source[0] - eps) & (t_target <= t_source[-1] + eps)
    out = np.full((len(t_target), values.shape[1]), np.nan)
    for column in range(values.shape[1]):
        series = values[:, column]
        if column in angle_columns:
            series = np.unwrap(series)
        out[valid, column] = np.interp(t_target[valid], t_source, series)
        if column in angle_columns:
            out[:, column] = wrap_angle(out[:, column])
    return out, valid


def raster_lookup(raster: np.ndarray, pixel_to_ego: np.ndarray, x: np.ndarray, y: np.ndarray, fill: int = -1):
    """Values of an ego-aligned raster at ego points (x, y), nearest pixel; ``fill`` outside the raster.
    ``pixel_to_ego``: the 2x3 affine map from a pixel's (column, row) index to the ego (x, y) of its centre."""
    affine = np.vstack([np.asarray(pixel_to_ego, np.float64), [0.0, 0.0, 1.0]])
    ego_to_pixel = np.linalg.inv(affine)
    cols = np.rint(ego_to_pixel[0, 0] * x + ego_to_pixel[0, 1] * y + ego_to_pixel[0, 2]).astype(np.int64)
    rows = np.rint(ego_to_pixel[1, 0] * x + ego_to_pixel[1, 1] * y + ego_to_pixel[1, 2]).astype(np.int64)
    inside = (rows >= 0) & (rows < raster.shape[0]) & (cols >= 0) & (cols < raster.shape[1])
    out = np.full(np.shape(x), fill, np.int64)
    out[inside] = raster[rows[inside], cols[inside]]
    return out
