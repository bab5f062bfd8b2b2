"""LEAD's own 123D recordings: how we recognise them, the three places where they depart from py123d's
conventions (corrected here and nowhere else), and LEAD's route planner for target points and the command.

LEAD's expert (``lead/expert/expert_py123d.py``) writes logs of dataset ``carla`` (split ``carla_*``) with py123d's
``carla_lincoln_mkz_2020`` vehicle. Its departures, each undone by one function below:

1. Ego dynamics (:func:`ego_dynamics`): ``dynamic_state_se3`` should be body-frame; LEAD writes CARLA's *world*
   velocity and acceleration with y negated, and CARLA's angular velocity unconverted (deg/s, left-handed). We
   rotate the vectors into the body frame by the ego heading and turn the z rate into ISO rad/s (-deg2rad).
2. Traffic lights (:func:`lights`): ``lane_id`` should be a map lane id; LEAD writes the CARLA waypoint's
   ``lane_id`` (a signed lane index within its road, e.g. -1). They are kept in extras as CARLA lane indices and
   never reach the scorer's red-light lanes.
3. LiDAR (:data:`lidar_z_offset`): points should be in the IMU (rear-axle) frame; LEAD shifts x to the rear axle
   but raises z by half the sensor height, and its ``lidar_to_imu_se3`` is the sensor pose relative to the vehicle
   centre. We lower z by that half height, which gives LEAD's own LiDAR frame (the one its route folders store).

LEAD's logs carry no target points and no command, and their route is py123d's driven path of the IMU (rear
axle). LEAD's planner tracks the vehicle *centre* along a plan of centre positions, so :func:`centre_path` rebuilds
the driven path of the centre (one point a metre); :func:`road_options` and :func:`sparse_plan` label and thin it
the way CARLA's planner and the leaderboard's ``downsample_route`` do, and LEAD's planner
(:mod:`lead_s2r.formats.lead_route`, the closed-loop agent's too) pops it.
"""

from typing import Any

import numpy as np

from lead_s2r.geometry import rotate

LEAD_DATASETS = ("carla", "lead123d")
LEAD_VEHICLE = "carla_lincoln_mkz_2020"
#: CARLA RoadOption codes, as LEAD stores ``command_raw``.
LEFT, RIGHT, LANEFOLLOW = 1, 2, 4
#: a route point turns when the path's mean curvature over :data:`TURN_WINDOW_M` either side of it is tighter
#: than a :data:`TURN_RADIUS_M` circle (a 10 m junction turn is then labelled from its first metre to its last).
TURN_RADIUS_M = 25.0
TURN_WINDOW_M = 1.5


def is_lead_log(log: dict[str, Any], ego_meta: dict[str, Any]) -> bool:
    """LEAD's logs: dataset ``carla``/``lead123d`` (or a ``carla_*`` split) recorded with the CARLA Lincoln."""
    dataset = str(log.get("dataset", "")).lower()
    split = str(log.get("split", "")).lower()
    carla = dataset in LEAD_DATASETS or split.startswith("carla")
    return carla and ego_meta.get("vehicle_name") == LEAD_VEHICLE


def ego_dynamics(dynamics: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Departure 1: (velocity, acceleration) in the body frame and the ISO yaw rate in rad/s from LEAD's
    world-frame (y already negated) vectors and CARLA's deg/s angular velocity."""
    velocity = rotate(dynamics[0:2], -yaw)
    acceleration = rotate(dynamics[3:5], -yaw)
    return velocity, acceleration, -float(np.deg2rad(dynamics[8]))


def lights(detections: list[tuple[int, int]]) -> dict[str, Any]:
    """Departure 2: LEAD's traffic lights as CARLA lane indices with their status (never map lane ids)."""
    return {"carla_lane_index": [lane for lane, _ in detections], "status": [status for _, status in detections]}


def lidar_z_offset(lidar_to_imu: np.ndarray) -> float:
    """Departure 3: how far LEAD raised its points (half the LiDAR's mounting height, from its ``lidar_to_imu_se3``)."""
    return float(lidar_to_imu[2]) / 2


def centre_path(poses: np.ndarray, rear_axle_to_center: float, spacing: float = 1.0) -> np.ndarray:
    """The driven path (M, 2) of the vehicle centre, resampled every ``spacing`` metres, from rear-axle poses."""
    centre = poses[:, :2] + rear_axle_to_center * np.column_stack([np.cos(poses[:, 2]), np.sin(poses[:, 2])])
    arc = np.r_[0.0, np.cumsum(np.hypot(*np.diff(centre, axis=0).T))]
    moving = np.r_[True, np.diff(arc) > 1e-6]  # a standstill repeats points
    at = np.arange(0.0, arc[-1], spacing) if arc[-1] > 0 else np.zeros(1)
    return np.column_stack([np.interp(at, arc[moving], centre[moving, k]) for k in (0, 1)])


def road_options(route: np.ndarray) -> np.ndarray:
    """CARLA RoadOption of each point of a dense route (M, 2): LEFT / RIGHT where the route curves tighter than
    :data:`TURN_RADIUS_M` (ISO: left is counter-clockwise), LANEFOLLOW elsewhere."""
    if len(route) < 2:
        return np.full(len(route), LANEFOLLOW)
    step = np.diff(route, axis=0)
    heading = np.unwrap(np.arctan2(step[:, 1], step[:, 0]))
    heading = np.r_[heading, heading[-1]]
    arc = np.r_[0.0, np.cumsum(np.hypot(step[:, 0], step[:, 1]))]
    ahead = np.interp(np.minimum(arc + TURN_WINDOW_M, arc[-1]), arc, heading)
    behind = np.interp(np.maximum(arc - TURN_WINDOW_M, 0.0), arc, heading)
    curvature = (ahead - behind) / (2 * TURN_WINDOW_M)
    return np.where(curvature > 1 / TURN_RADIUS_M, LEFT, np.where(curvature < -1 / TURN_RADIUS_M, RIGHT, LANEFOLLOW))


def sparse_plan(route: np.ndarray, options: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """The leaderboard's ``downsample_route``: keep the first and last point, every point where the option
    changes, and a point once more than ``spacing`` metres were travelled since the last kept one (counted, as
    there, over the steps between points that are not kept)."""
    keep, travelled = [], 0.0
    for k in range(len(route)):
        if k == 0 or options[k] != options[k - 1] or travelled > spacing or k == len(route) - 1:
            keep.append(k)
            travelled = 0.0
        else:
            travelled += float(np.hypot(*(route[k] - route[k - 1])))
    return route[keep], options[keep]
