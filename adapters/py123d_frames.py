"""py123d's frames -> ours: SE3 rows (x, y, z, qw, qx, qy, qz) to planar poses and 4x4 transforms, and the
ego's rear axle from its IMU pose.

py123d's conventions (docs/notes/conventions) are ISO 8855 like ours: x forward, y left, z up, scalar-first unit
quaternions, Tait-Bryan ZYX angles. What differs is the origin: an ego state is the pose of the *IMU* in the world,
and the vehicle metadata gives ``rear_axle_to_imu_se3`` (the rear-axle frame expressed in the IMU frame; identity for
most datasets). Every sample here is in the rear-axle frame at t0, so IMU poses become rear-axle poses by composing
with that extrinsic, and IMU-frame sensor extrinsics and points go through its inverse. z stays relative to the
rear-axle frame: the axle's height above the ground is not in a 123D log.
"""

from typing import Any

import numpy as np

from lead_s2r.geometry import quaternion_matrix

#: metres from the world origin (and m/s) that nothing in a log reaches: UTM northings reach 1e7, while a damaged
#: double reaches 1e308, which overflows float32 on the way to a sample and the products of transforms
MAX_COORDINATE = 1e8


def pose_matrix(pose: np.ndarray) -> np.ndarray:
    """(..., 7) SE3 rows -> (..., 4, 4) homogeneous transforms."""
    pose = np.asarray(pose, np.float64)
    out = np.zeros((*pose.shape[:-1], 4, 4))
    out[..., :3, :3] = quaternion_matrix(pose[..., 3:7])
    out[..., :3, 3] = pose[..., :3]
    out[..., 3, 3] = 1.0
    return out


def rear_axle_poses(imu: np.ndarray, rear_axle_to_imu: np.ndarray) -> np.ndarray:
    """World poses of the rear axle (..., 7 -> ..., 4, 4) from the IMU's: ``T_world_imu @ T_imu_rear``."""
    return pose_matrix(imu) @ pose_matrix(rear_axle_to_imu)


def to_rear_axle(imu_to_x: np.ndarray, rear_axle_to_imu: np.ndarray) -> np.ndarray:
    """An IMU-frame extrinsic (4, 4) re-expressed in the rear-axle frame: ``inv(T_imu_rear) @ T_imu_x``."""
    return np.linalg.inv(pose_matrix(rear_axle_to_imu)) @ imu_to_x


def vehicle(meta: dict[str, Any], centre: np.ndarray, rear: np.ndarray) -> dict[str, float]:
    """``meta.vehicle`` from py123d's ego metadata and its ``center_to_imu_se3`` and ``rear_axle_to_imu_se3``: the
    centre's offset ahead of the rear axle is ``center_to_imu.x - rear_axle_to_imu.x``."""
    return {
        "length": float(meta["length"]),
        "width": float(meta["width"]),
        "height": float(meta["height"]),
        "wheel_base": float(meta["wheel_base"]),
        "rear_axle_to_center": float(centre[0] - rear[0]),
    }
