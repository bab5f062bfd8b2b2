"""The leaderboard sensor rig of a model, and one tick of leaderboard sensor data -> a schema v1 sample.

The sample is what the CARLA adapter writes for a recorded LEAD frame (ISO rear-axle frame, JPEG mosaic with the
rig's per-tile calibration, LiDAR ``x, y, z, time``, radar ``x, y, z, v, sensor``), so the training transforms turn
it into model inputs unchanged: one preprocessing path for training and driving.

Leaderboard 2.0 hands data over as its ``SensorInterface`` shapes it: cameras BGRA uint8 (H, W, 4); LiDAR float32
(N, 4) x, y, z, intensity in the sensor frame; radar float32 (N, 4) depth, altitude, azimuth, velocity (CARLA's raw
order flipped); GNSS [lat, lon, alt]; IMU [ax, ay, az, gx, gy, gz, compass]; speedometer ``{"speed": m/s}``.
Like LEAD, the mosaic goes through a JPEG round trip (quality 90) because the training data was JPEG; the LiDAR is the
current tick's two half sweeps, unfiltered, as LEAD's recorded point clouds are.

A tick's data is checked as it is read: a sensor missing, a reading of another shape or type is a
:class:`SensorInputError` naming the sensor (the rig and the simulator disagree: no later tick would be better); a
LiDAR or radar row that is not a number (or 10 km away) is no return and is dropped; a GNSS, IMU or speedometer value
that is not a number or out of range makes the tick unusable (:meth:`PoseReading.unusable`; the agent brakes that tick,
docs/closed_loop.md).
"""

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from lead_s2r.closed_loop.route import Navigation
from lead_s2r.errors import UserError
from lead_s2r.fields import is_number
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
#: Values per reading: GNSS [lat, lon, alt], IMU [ax, ay, az, gx, gy, gz, compass]; LiDAR and radar columns.
GNSS_SIZE, IMU_SIZE, POINT_COLUMNS = 3, 7, 4
#: The IMU's compass value (radians); NaN on CARLA's first ticks.
COMPASS = 6
#: The largest magnitude of each GNSS (lat, lon degrees, alt m), IMU (m/s^2, rad/s, compass rad) and speedometer (m/s)
#: value a tick can be driven on; no car or planet gives more.
POSE_READING_LIMITS = {
    GNSS_ID: np.array([90.0, 180.0, 1e5]),
    IMU_ID: np.array([1e3, 1e3, 1e3, 1e3, 1e3, 1e3, 2 * np.pi]),
    SPEED_ID: np.array([1e3]),
}
#: A LiDAR or radar value beyond this (metres, m/s, radians) is no return: CARLA's sensors reach 100 m.
MAX_POINT_VALUE = 1e4
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
    specs = [
        {"type": "sensor.camera.rgb", **_mount(*camera.position, camera.yaw_deg), "width": camera.width,
         "height": camera.height, "fov": camera.fov_deg, "id": f"rgb_{camera.number}"}
        for camera in CAMERA_RIGS[rig.cameras]
    ]  # fmt: skip
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


class SensorInputError(UserError, ValueError):
    """A tick's sensor data the agent cannot read; one line naming the sensor."""


def reading(input_data: dict[str, Any], sensor_id: str) -> Any:
    """The data of one sensor (``input_data[id] = (frame, data)``), or an error naming the sensor."""
    if sensor_id not in input_data:
        raise SensorInputError(f"sensor {sensor_id!r}: missing from the tick's input_data (got {sorted(input_data)})")
    entry = input_data[sensor_id]
    if not (isinstance(entry, tuple | list) and len(entry) == 2):
        raise SensorInputError(f"sensor {sensor_id!r}: expected a (frame, data) pair, got {type(entry).__name__}")
    return entry[1]


def _numbers(value: Any, sensor_id: str, shape: str) -> np.ndarray:
    """``value`` as a float64 array, or an error naming the sensor and the ``shape`` expected."""
    try:
        return np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise SensorInputError(f"sensor {sensor_id!r}: expected {shape}, got {type(value).__name__}") from None


def vector(input_data: dict[str, Any], sensor_id: str, size: int) -> np.ndarray:
    """A GNSS or IMU reading as float64 (size,), any value possibly NaN (:meth:`PoseReading.unusable` says)."""
    values = _numbers(reading(input_data, sensor_id), sensor_id, f"{size} numbers")
    if values.shape != (size,):
        raise SensorInputError(f"sensor {sensor_id!r}: expected {size} numbers, got shape {values.shape}")
    return values


def speed_reading(input_data: dict[str, Any]) -> float:
    """The speedometer's m/s (the leaderboard's ``{"speed": value}``)."""
    data = reading(input_data, SPEED_ID)
    value = data.get("speed") if isinstance(data, dict) else None
    if not is_number(value, finite=False):  # NaN or out of range: PoseReading.unusable brakes the tick
        raise SensorInputError(f"sensor {SPEED_ID!r}: expected {{'speed': a number}}, got {data!r:.80}")
    return float(value)


@dataclass(frozen=True)
class PoseReading:
    """A tick's GNSS, IMU and speedometer, read once: the pose, ego state and controllers use the same values."""

    gnss: np.ndarray
    imu: np.ndarray
    speed: float

    @classmethod
    def read(cls, input_data: dict[str, Any]) -> "PoseReading":
        """The tick's readings; a missing or misshapen one raises :class:`SensorInputError`."""
        gnss, imu = vector(input_data, GNSS_ID, GNSS_SIZE), vector(input_data, IMU_ID, IMU_SIZE)
        return cls(gnss, imu, speed_reading(input_data))

    def unusable(self) -> str | None:
        """Why this tick's position, heading or speed cannot be used (a value that is not a number or beyond
        :data:`POSE_READING_LIMITS`: the position filter would diverge on it), None when they can."""
        imu = self.imu.copy()  # the simulator's array stays as it came
        imu[COMPASS] = 0.0 if np.isnan(imu[COMPASS]) else imu[COMPASS]  # CARLA's first ticks: north (compass_to_yaw)
        readings = {GNSS_ID: self.gnss, IMU_ID: imu, SPEED_ID: np.array([self.speed])}
        bad = [name for name, values in readings.items() if not (np.abs(values) <= POSE_READING_LIMITS[name]).all()]
        return f"sensors {bad}: a value that is not a number or out of range" if bad else None


def sensor_points(input_data: dict[str, Any], sensor_id: str) -> np.ndarray:
    """A LiDAR or radar reading as float64 (N, 4) without the rows that are no return (:data:`MAX_POINT_VALUE`)."""
    points = _numbers(reading(input_data, sensor_id), sensor_id, f"an (N, {POINT_COLUMNS}) array")
    if points.ndim != 2 or points.shape[1] != POINT_COLUMNS:
        raise SensorInputError(f"sensor {sensor_id!r}: expected an (N, {POINT_COLUMNS}) array, got shape "
                               f"{points.shape}")  # fmt: skip
    return points[(np.abs(points) < MAX_POINT_VALUE).all(axis=1)]  # False for NaN


def mosaic_jpeg(input_data: dict[str, Any], rig: str, quality: int) -> bytes:
    """The rig's cameras stitched left to right, the top rows LEAD keeps, as JPEG bytes."""
    tiles = []
    for camera in CAMERA_RIGS[rig]:
        sensor_id = f"rgb_{camera.number}"
        data = reading(input_data, sensor_id)
        image = data if isinstance(data, np.ndarray) else np.zeros(0)
        if image.shape != (camera.height, camera.width, 4) or image.dtype != np.uint8:
            raise SensorInputError(f"sensor {sensor_id!r}: expected a BGRA uint8 {camera.height}x{camera.width}x4 "
                                   f"image, got {type(data).__name__} {getattr(data, 'dtype', '')} "
                                   f"{getattr(data, 'shape', '')}")  # fmt: skip
        tiles.append(image[: camera.stored_height, :, :3])
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(np.hstack(tiles)), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("OpenCV could not JPEG-encode the camera mosaic")
    return data.tobytes()


def lidar_points(input_data: dict[str, Any]) -> np.ndarray:
    """Both half sweeps in the ISO rear-axle frame: float32 (N, 4) x, y, z, time (0: this tick)."""
    clouds = []
    for name, position, yaw in LIDARS:
        points = sensor_points(input_data, name)
        clouds.append(carla_points_to_iso(sensor_to_carla_ego(points[:, :3], position, yaw)))
    points = np.concatenate(clouds)
    return np.column_stack([points, np.zeros(len(points))]).astype(np.float32)


def radar_points(input_data: dict[str, Any]) -> np.ndarray:
    """The four radars in the ISO rear-axle frame: float32 (N, 5) x, y, z, radial velocity, sensor index."""
    rows = []
    for index, (name, position, yaw) in enumerate(RADARS):
        local = radar_to_cartesian(sensor_points(input_data, name))
        ego = carla_points_to_iso(sensor_to_carla_ego(local[:, :3], position, yaw))
        rows.append(np.column_stack([ego, local[:, 3], np.full(len(ego), index)]))
    return np.concatenate(rows).astype(np.float32)


def ego_state(pose: PoseReading, navigation: Navigation) -> dict[str, Any]:
    """``meta.ego`` from the speedometer, the IMU (CARLA's y-right vehicle axes) and the route command."""
    imu, speed = pose.imu, pose.speed
    return {
        "speed": speed,
        "velocity": [speed, 0.0],
        "acceleration": [float(imu[0]), -float(imu[1])],
        "yaw_rate": -float(imu[5]),
        "command": int(ROAD_OPTION.get(navigation.command, Command.UNKNOWN)),
        "command_raw": navigation.command,
    }


def build_sample(
    input_data: dict[str, Any], pose: PoseReading, rig: Rig, navigation: Navigation, frame: int, timestamp: float,
    jpeg_quality: int,
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
        "ego": ego_state(pose, navigation),
        "vehicle": dict(EGO_VEHICLE),
        "cameras": camera_calibration(rig.cameras),
        "has": {name: True for name in sample if name != "__key__"} | {"future": False, "route": False},
        "extras": {DATASET: {"target_dataset": rig.cameras}},
        **meta,
    }
    return sample
