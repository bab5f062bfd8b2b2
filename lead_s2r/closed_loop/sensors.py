"""The leaderboard sensor rig of a model, and one tick of leaderboard sensor data -> a schema v1 sample.

The sample is what the CARLA adapter writes for a recorded LEAD frame (ISO rear-axle frame, JPEG mosaic with the
rig's per-tile calibration, LiDAR ``x, y, z, time``, radar ``x, y, z, v, sensor``), so the training transforms turn
it into model inputs unchanged: one preprocessing path for training and driving.

Leaderboard 2.0 hands data over as its ``SensorInterface`` shapes it: cameras BGRA uint8 (H, W, 4); LiDAR float32
(N, 4) x, y, z, intensity in the sensor frame; radar float32 (N, 4) depth, altitude, azimuth, velocity (CARLA's raw
order flipped); GNSS [lat, lon, alt]; IMU [ax, ay, az, gx, gy, gz, compass]; speedometer ``{"speed": m/s}``.
Like LEAD, the mosaic goes through a JPEG round trip (quality 90) because the training data was JPEG; the LiDAR is the
current tick's two half sweeps, unfiltered, as LEAD's recorded point clouds are.
"""

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from lead_s2r.closed_loop.route import Navigation
from lead_s2r.formats.carla_rig import (
    CAMERA_RIGS,
    EGO_VEHICLE,
    MOSAIC_ID,
    ROAD_OPTION,
    camera_calibration,
    radar_to_cartesian,
    sensor_to_carla_ego,
)
from lead_s2r.geometry import carla_points_to_iso
from lead_s2r.schema import SCHEMA_VERSION, Command

#: LEAD's two LiDARs (``use_two_lidars``): both at the roof centre, facing opposite sides; each delivers a half sweep.
LIDARS = (("lidar_0", (0.0, 0.0, 2.5), -90.0), ("lidar_1", (0.0, 0.0, 2.5), -270.0))
#: LEAD's four radars: id, position (CARLA, m), yaw (deg); in the adapter's sensor order radar1..radar4.
RADARS = (
    ("radar_1", (2.6, 0.0, 0.6), -45.0),
    ("radar_2", (2.6, 0.0, 0.6), 45.0),
    ("radar_3", (-2.6, 0.0, 0.6), 135.0),
    ("radar_4", (-2.6, 0.0, 0.6), 225.0),
)
RADAR_FOV = (90.0, 0.1)  # horizontal, vertical, degrees
IMU_TICK, GNSS_TICK, SPEEDOMETER_HZ = 0.05, 0.01, 20
GNSS_ID, IMU_ID, SPEED_ID = "gps", "imu", "speed"
#: LEAD's ``jpeg_quality`` for the closed-loop image round trip.
JPEG_QUALITY = 90
DATASET = "carla_lead"


@dataclass(frozen=True)
class Rig:
    """Which sensors a model reads: the LEAD camera rig, LiDAR (TFv6's raster input), radar."""

    cameras: str
    lidar: bool
    radar: bool


def _mount(x: float, y: float, z: float, yaw: float) -> dict[str, float]:
    return {"x": x, "y": y, "z": z, "roll": 0.0, "pitch": 0.0, "yaw": yaw}


def sensor_specs(rig: Rig) -> list[dict[str, Any]]:
    """The leaderboard ``sensors()`` list of a rig."""
    specs: list[dict[str, Any]] = []
    for camera in CAMERA_RIGS[rig.cameras]:
        specs.append(
            {"type": "sensor.camera.rgb", **_mount(*camera.position, camera.yaw_deg), "width": camera.width,
             "height": camera.height, "fov": camera.fov_deg, "id": f"rgb_{camera.number}"}
        )  # fmt: skip
    if rig.lidar:
        specs += [{"type": "sensor.lidar.ray_cast", **_mount(*pos, yaw), "id": name} for name, pos, yaw in LIDARS]
    if rig.radar:
        specs += [
            {"type": "sensor.other.radar", **_mount(*pos, yaw), "horizontal_fov": RADAR_FOV[0],
             "vertical_fov": RADAR_FOV[1], "id": name}
            for name, pos, yaw in RADARS
        ]  # fmt: skip
    specs += [
        {"type": "sensor.other.imu", **_mount(0.0, 0.0, 0.0, 0.0), "sensor_tick": IMU_TICK, "id": IMU_ID},
        {"type": "sensor.other.gnss", **_mount(0.0, 0.0, 0.0, 0.0), "sensor_tick": GNSS_TICK, "id": GNSS_ID},
        {"type": "sensor.speedometer", "reading_frequency": SPEEDOMETER_HZ, "id": SPEED_ID},
    ]
    return specs


def reading(input_data: dict[str, Any], sensor_id: str) -> Any:
    """The data of one sensor (``input_data[id] = (frame, data)``), or an error naming the missing id."""
    if sensor_id not in input_data:
        raise KeyError(f"leaderboard input_data has no sensor {sensor_id!r} (got {sorted(input_data)})")
    return input_data[sensor_id][1]


def mosaic_jpeg(input_data: dict[str, Any], rig: str, quality: int = JPEG_QUALITY) -> bytes:
    """The rig's cameras stitched left to right, the top rows LEAD keeps, as JPEG bytes."""
    tiles = []
    for camera in CAMERA_RIGS[rig]:
        image = np.asarray(reading(input_data, f"rgb_{camera.number}"))
        if image.shape != (camera.height, camera.width, 4):
            raise ValueError(f"camera rgb_{camera.number}: expected BGRA {camera.height}x{camera.width}x4, got "
                             f"{image.shape}")  # fmt: skip
        tiles.append(image[: camera.stored_height, :, :3])
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(np.hstack(tiles)), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("OpenCV could not JPEG-encode the camera mosaic")
    return data.tobytes()


def lidar_points(input_data: dict[str, Any]) -> np.ndarray:
    """Both half sweeps in the ISO rear-axle frame: float32 (N, 4) x, y, z, time (0: this tick)."""
    clouds = []
    for name, position, yaw in LIDARS:
        points = np.asarray(reading(input_data, name), np.float64).reshape(-1, 4)
        clouds.append(carla_points_to_iso(sensor_to_carla_ego(points[:, :3], position, yaw)))
    points = np.concatenate(clouds)
    return np.column_stack([points, np.zeros(len(points))]).astype(np.float32)


def radar_points(input_data: dict[str, Any]) -> np.ndarray:
    """The four radars in the ISO rear-axle frame: float32 (N, 5) x, y, z, radial velocity, sensor index."""
    rows = []
    for index, (name, position, yaw) in enumerate(RADARS):
        detections = np.asarray(reading(input_data, name), np.float64).reshape(-1, 4)
        local = radar_to_cartesian(detections)
        ego = carla_points_to_iso(sensor_to_carla_ego(local[:, :3], position, yaw))
        rows.append(np.column_stack([ego, local[:, 3], np.full(len(ego), index)]))
    return np.concatenate(rows).astype(np.float32)


def ego_state(input_data: dict[str, Any], navigation: Navigation) -> dict[str, Any]:
    """``meta.ego`` from the speedometer, the IMU (CARLA's y-right vehicle axes) and the route command."""
    imu = np.asarray(reading(input_data, IMU_ID), np.float64)
    speed = float(reading(input_data, SPEED_ID)["speed"])
    return {
        "speed": speed,
        "velocity": [speed, 0.0],
        "acceleration": [float(imu[0]), -float(imu[1])],
        "yaw_rate": -float(imu[5]),
        "command": int(ROAD_OPTION.get(navigation.command, Command.UNKNOWN)),
        "command_raw": navigation.command,
    }


def build_sample(
    input_data: dict[str, Any], rig: Rig, navigation: Navigation, frame: int, timestamp: float,
    jpeg_quality: int = JPEG_QUALITY,
) -> dict[str, Any]:  # fmt: skip
    """One tick of sensor data as a schema v1 sample of the CARLA source (what the adapter writes)."""
    sample: dict[str, Any] = {
        "__key__": f"closed_loop_{frame:06d}",
        "past": np.zeros((1, 4), np.float32),
        "target_points": navigation.target_points.astype(np.float32),
        f"cam_{MOSAIC_ID}": mosaic_jpeg(input_data, rig.cameras, jpeg_quality),
    }
    meta: dict[str, Any] = {}
    if rig.lidar:
        sample["lidar"] = lidar_points(input_data)
        meta["lidar_columns"] = ["x", "y", "z", "time"]
    if rig.radar:
        sample["radar"] = radar_points(input_data)
        meta["radar_sensors"] = [name for name, _, _ in RADARS]
    sample["meta"] = {
        "schema_version": SCHEMA_VERSION,
        "dataset": DATASET,
        "split": "closed_loop",
        "log_id": "closed_loop",
        "frame_idx": frame,
        "timestamp_us": round(timestamp * 1e6),
        "is_synthetic": True,
        "location": None,
        "adapter": "closed_loop",
        "adapter_version": "1",
        "ego": ego_state(input_data, navigation),
        "vehicle": dict(EGO_VEHICLE),
        "cameras": camera_calibration(rig.cameras),
        "has": {name: True for name in sample if name != "__key__"} | {"future": False, "route": False},
        "extras": {DATASET: {"target_dataset": rig.cameras}},
        **meta,
    }
    return sample
