"""LEAD's CARLA sensor rigs and CARLA sensor frames -> the ISO rear-axle ego frame, shared by the CARLA adapter and
the closed-loop agent.

One place for both on purpose: the adapter turns recorded frames into samples and the agent turns live sensor data
into the same samples, so a camera calibration or a frame flip that differed between them would make the driving
model see inputs it was never trained on. CARLA sensor frames are left-handed (x forward, y right, z up, yaw
clockwise in degrees); sensor positions are relative to the vehicle centre.
"""

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from lead_s2r.geometry import CARLA_REAR_AXLE_TO_CENTER, carla_points_to_iso, homogeneous, rotate
from lead_s2r.schema import Command

MOSAIC_ID = "carla_mosaic"


@dataclass(frozen=True)
class RigCamera:
    """One camera of a LEAD rig (``config_base.camera_calibration``): CARLA position (m, y right) and yaw (deg,
    clockwise); rendered ``width`` x ``height`` with a horizontal ``fov_deg``. LEAD keeps the top ``stored_height``
    rows, so the principal point stays at ``height / 2``."""

    name: str
    number: int  # LEAD's camera index: native name rgb_<number>
    position: tuple[float, float, float]
    yaw_deg: float
    width: int = 384
    height: int = 384
    stored_height: int = 384
    fov_deg: float = 60.0


def _navsim_camera(name: str, number: int, position: tuple[float, float, float], yaw_deg: float) -> RigCamera:
    """nuPlan's calibration as LEAD renders it in CARLA: 1920x1120 / 4, 1080 / 4 rows kept, 63.71 deg."""
    return RigCamera(name, number, position, yaw_deg, width=480, height=280, stored_height=270, fov_deg=63.71)


#: LEAD's camera rigs by ``dataset_information.target_dataset``, cameras in stitch order (left to right). Roll and
#: pitch of the NAVSIM-matched rig (under 2.4 deg) are left out, as for the Leaderboard rigs, which have none.
CAMERA_RIGS: dict[str, tuple[RigCamera, ...]] = {
    "CARLA_LEADERBOARD2_3CAMERAS": (
        RigCamera("left", 1, (0.1, -0.35, 2.25), -54.5),
        RigCamera("front", 2, (0.35, 0.0, 2.25), 0.0),
        RigCamera("right", 3, (0.1, 0.35, 2.25), 54.5),
    ),
    # stitched |1 2 3|6 5 4| (LEAD issue #63): the rear cameras read like a rear-view mirror
    "CARLA_LEADERBOARD2_6CAMERAS": (
        RigCamera("front_left", 1, (0.0, -0.3, 2.25), -57.5),
        RigCamera("front", 2, (0.25, 0.0, 2.25), 0.0),
        RigCamera("front_right", 3, (0.0, 0.3, 2.25), 57.5),
        RigCamera("back_left", 6, (-0.3, -0.3, 2.25), -122.5),
        RigCamera("back", 5, (-0.55, 0.0, 2.25), 180.0),
        RigCamera("back_right", 4, (-0.3, 0.3, 2.25), 122.5),
    ),
    "CARLA_PY123D_1CAMERA": (
        RigCamera("front", 1, (-1.5, 0.0, 2.0), 0.0, width=1024, height=512, stored_height=384, fov_deg=110.0),
    ),
    "NAVSIM_4CAMERAS": (
        _navsim_camera("front_left", 1, (0.2568, -0.1491, 1.9612), -56.01),
        _navsim_camera("front", 2, (0.3436, 0.0098, 1.9521), -1.03),
        _navsim_camera("front_right", 3, (0.3628, 0.1638, 1.9540), 54.26),
        _navsim_camera("back", 4, (-1.8372, 0.0231, 1.9105), 180.0),
    ),
}
#: The rig of routes whose metas name none (LEAD's default ``carla_leaderboard2`` data, the paper's).
DEFAULT_TARGET_DATASET = "CARLA_LEADERBOARD2_3CAMERAS"
#: CARLA's Lincoln MKZ 2020 ego: half extents from LEAD's config.
EGO_HALF_EXTENT = (2.4508416652679443, 1.0641621351242065, 0.7553732395172119)
#: ``meta.vehicle`` of every CARLA sample, converted or driven.
EGO_VEHICLE = {
    "length": 2 * EGO_HALF_EXTENT[0],
    "width": 2 * EGO_HALF_EXTENT[1],
    "height": 2 * EGO_HALF_EXTENT[2],
    "wheel_base": 2.85,  # of the real car
    "rear_axle_to_center": CARLA_REAR_AXLE_TO_CENTER,
}
#: CARLA RoadOption -> unified command (VOID = -1 and anything unknown -> UNKNOWN).
ROAD_OPTION = {
    1: Command.LEFT,
    2: Command.RIGHT,
    3: Command.STRAIGHT,
    4: Command.LANE_FOLLOW,
    5: Command.CHANGE_LANE_LEFT,
    6: Command.CHANGE_LANE_RIGHT,
}


def camera_calibration(target_dataset: str = DEFAULT_TARGET_DATASET, height: int | None = None) -> list[dict[str, Any]]:
    """Per-tile pinhole calibration of a rig's mosaic, ``height`` rows stored (default: the rows LEAD keeps), in the
    ISO rear-axle ego frame (OpenCV camera axes)."""
    cam_axes = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])  # camera x/y/z in ego axes (rows)
    cameras, x0 = [], 0
    for camera in CAMERA_RIGS[target_dataset]:
        focal = camera.width / (2 * math.tan(math.radians(camera.fov_deg) / 2))
        rotation = rotate(cam_axes, -math.radians(camera.yaw_deg)).T  # CARLA yaw is clockwise
        cam_to_ego = homogeneous(rotation, carla_points_to_iso(np.array(camera.position)))
        cameras.append(
            {
                "id": MOSAIC_ID,
                "native_name": f"rgb_{camera.number}",
                "tile_name": camera.name,
                "width": camera.width,
                "height": camera.stored_height if height is None else height,
                "K": [[focal, 0.0, camera.width / 2], [0.0, focal, camera.height / 2], [0.0, 0.0, 1.0]],
                "distortion": [0.0] * 5,
                "cam_to_ego": cam_to_ego.tolist(),
                "tile": [x0, camera.width],
            }
        )
        x0 += camera.width
    return cameras


def sensor_to_carla_ego(points: np.ndarray, position: tuple[float, float, float], yaw_deg: float) -> np.ndarray:
    """Points (N, 3+) in a CARLA sensor frame mounted at ``position`` with ``yaw_deg`` -> the CARLA ego-centre frame.

    In CARLA's left-handed frame a positive (clockwise seen from above) yaw turns x towards y, which in (x, y-right)
    coordinates is the ordinary rotation by +yaw."""
    out = rotate(np.asarray(points, np.float64), math.radians(yaw_deg))
    out[:, :3] += np.asarray(position, np.float64)
    return out


def radar_to_cartesian(detections: np.ndarray) -> np.ndarray:
    """Radar detections (N, 4) = depth, altitude, azimuth, velocity (radians, as the leaderboard's sensor interface
    flips CARLA's raw velocity/azimuth/altitude/depth) -> (N, 4) x, y, z, velocity in the radar's own frame."""
    depth, altitude, azimuth, velocity = np.asarray(detections, np.float64).T
    return np.column_stack(
        [
            depth * np.cos(altitude) * np.cos(azimuth),
            depth * np.cos(altitude) * np.sin(azimuth),
            depth * np.sin(altitude),
            velocity,
        ]
    )
