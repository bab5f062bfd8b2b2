"""Leaderboard-shaped sensor data and global plans made from a synthetic LEAD route folder (the inverse of the
agent's sensor conversion, written independently: sensor frames, radar polar coordinates, CARLA's geo mapping)."""

import math
from pathlib import Path

import cv2
import numpy as np

from lead_s2r.geometry import rotate
from lead_s2r_adapters.carla_lead_io import read_laz, read_pickle, read_radar

EARTH_RADIUS = 6378137.0
#: A Town13-like geo reference, far from (0, 0).
REFERENCE = (49.0, 8.0)
LIDAR_MOUNTS = (("lidar_0", -90.0), ("lidar_1", -270.0))
RADAR_MOUNTS = (((2.6, 0.0, 0.6), -45.0), ((2.6, 0.0, 0.6), 45.0), ((-2.6, 0.0, 0.6), 135.0), ((-2.6, 0.0, 0.6), 225.0))


def world_to_gnss(world: np.ndarray, reference: tuple[float, float] = REFERENCE) -> np.ndarray:
    """CARLA's location -> geolocation (LibCarla GeoLocation: Mercator at the reference's scale, y flipped)."""
    lat0, lon0 = reference
    scale = math.cos(math.radians(lat0))
    mx = scale * math.radians(lon0) * EARTH_RADIUS + world[:, 0]
    my = scale * EARTH_RADIUS * math.log(math.tan((90.0 + lat0) * math.pi / 360.0)) - world[:, 1]
    lon = mx * 180.0 / (math.pi * EARTH_RADIUS * scale)
    lat = 360.0 * np.arctan(np.exp(my / (EARTH_RADIUS * scale))) / math.pi - 90.0
    return np.column_stack([lat, lon])


def to_sensor(points: np.ndarray, position: tuple[float, float, float], yaw_deg: float) -> np.ndarray:
    """CARLA ego-centre points (N, 3) -> a sensor frame mounted at ``position`` with ``yaw_deg``."""
    return rotate(np.asarray(points, np.float64) - np.asarray(position), -math.radians(yaw_deg))


def sensor_data(folder: Path, frame: int) -> dict:
    """``input_data`` as leaderboard 2.0 hands it to ``run_step`` for one recorded frame (3-camera rig)."""
    name = f"{frame:04d}"
    meta = read_pickle(folder / "metas" / f"{name}.pkl")
    mosaic = cv2.imread(str(folder / "rgb" / f"{name}.jpg"), cv2.IMREAD_COLOR)
    data: dict = {}
    for number in (1, 2, 3):
        tile = mosaic[:, (number - 1) * 384 : number * 384]
        data[f"rgb_{number}"] = (frame, np.dstack([tile, np.full(tile.shape[:2], 255, np.uint8)]))
    points, _ = read_laz(folder / "lidar" / f"{name}.laz")
    halves = (points[points[:, 1] < 0], points[points[:, 1] >= 0])
    for (sensor, yaw), half in zip(LIDAR_MOUNTS, halves, strict=True):
        local = to_sensor(half, (0.0, 0.0, 2.5), yaw)
        data[sensor] = (frame, np.column_stack([local, np.ones(len(local))]).astype(np.float32))
    clouds = read_radar(folder / "radar" / f"{name}.npz")
    for index, (cloud, (position, yaw)) in enumerate(zip(clouds, RADAR_MOUNTS, strict=True)):
        local = to_sensor(cloud[:, :3], position, yaw)
        depth = np.linalg.norm(local, axis=1)
        altitude, azimuth = np.arcsin(local[:, 2] / depth), np.arctan2(local[:, 1], local[:, 0])
        detections = np.column_stack([depth, altitude, azimuth, cloud[:, 3]])  # the leaderboard's flipped order
        data[f"radar_{index + 1}"] = (frame, detections.astype(np.float32))
    lat, lon = world_to_gnss(np.array([meta["pos_global"][:2]]))[0]
    data["gps"] = (frame, np.array([lat, lon, 0.0]))
    compass = math.pi / 2 + meta["theta"]  # CARLA yaw is clockwise from +x; the compass is clockwise from -y
    imu = [meta["accel_x"], meta["accel_y"], 9.81, 0.0, 0.0, meta["angular_velocity_z"], compass]
    data["imu"] = (frame, np.array(imu))
    data["speed"] = (frame, {"speed": meta["speed"]})
    return data


def global_plan(folder: Path, tp_distance: float = 3.25) -> tuple[list, list]:
    """(gps route, world route) as the leaderboard passes them, from frame 0's remaining target points."""
    import carla

    meta = read_pickle(folder / "metas" / "0000.pkl")
    points = np.asarray(meta[f"next_target_points_{tp_distance}"], np.float64)
    commands = [int(c) for c in meta[f"next_commands_{tp_distance}"]]
    gnss = world_to_gnss(points[:, :2])
    world = [(carla.Transform(carla.Location(*map(float, p))), c) for p, c in zip(points, commands, strict=True)]
    gps = [({"lat": g[0], "lon": g[1], "z": 0.0}, c) for g, c in zip(gnss, commands, strict=True)]
    return gps, world
