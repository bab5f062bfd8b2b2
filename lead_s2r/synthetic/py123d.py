"""Write tiny 123D logs and maps with py123d's own writers (``ArrowLogWriter``, ``ArrowMapWriter``), so the
py123d adapter is tested against the real library's files rather than our idea of them.

Two kinds of log, both drives of :mod:`lead_s2r.synthetic.carla_lead` (CARLA world, 20 Hz) moved to py123d's ISO
world (y and yaw negated) and written every second tick (10 Hz):

- :func:`write_log`: a log as py123d's dataset parsers write one (nuPlan labels, body-frame ego dynamics, a rear
  axle 0.4 m behind the IMU, one JPEG front camera, IPC- or LAZ-coded LiDAR in the IMU frame, traffic lights on
  map lane ids) with a map whose lanes follow the drive (approach lane, a turn connector in an intersection, exit).
  The CARLA scene's oncoming car (:data:`ONCOMING`) and walker cross the left turn's exit, so this log leaves the
  car out and keeps the walker standing on the kerb: its logged future is a collision-free plan to score.
- :func:`write_lead_log`: the route folder :func:`lead_s2r.synthetic.carla_lead.write_route` writes for the same
  ``index``/``frames``/seed, as LEAD's ``expert_py123d.py`` would have logged it, with its three departures (world-frame
  velocity in the body field and deg/s yaw rate, CARLA lane indices for traffic lights, LiDAR raised by half the sensor
  height), its default-label boxes (no traffic-light boxes, emergency vehicles as VEHICLE) and one front camera. Its
  vehicle's centre sits :data:`CARLA_REAR_AXLE_TO_CENTER` ahead of the IMU, our CARLA constant, so the two conversions
  of one drive agree to float precision (real LEAD logs carry py123d's 1.649 m, read from the log).
Needs py123d installed (``pip install --no-deps "py123d>=0.7,<0.8"`` plus the ``py123d-writers`` extra).
"""

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from lead_s2r.errors import UserError

try:
    from py123d.api.map.arrow.arrow_map_writer import ArrowMapWriter
    from py123d.api.scene.arrow.arrow_log_writer import ArrowLogWriter
    from py123d.api.scene.arrow.utils.log_writer_config import LogWriterConfig
    from py123d.datatypes import (
        BoxDetectionAttributes,
        BoxDetectionSE3,
        BoxDetectionsSE3,
        BoxDetectionsSE3Metadata,
        Intersection,
        IntersectionType,
        Lane,
        LaneGroup,
        LaneType,
        TrafficLightDetection,
        TrafficLightDetections,
        TrafficLightStatus,
    )
    from py123d.datatypes.detections.box_detection_label import DefaultBoxDetectionLabel
    from py123d.datatypes.metadata.log_metadata import LogMetadata
    from py123d.datatypes.metadata.map_metadata import MapMetadata
    from py123d.datatypes.sensors.base_camera import CameraID
    from py123d.datatypes.sensors.lidar import Lidar, LidarFeature, LidarID, LidarMetadata
    from py123d.datatypes.sensors.pinhole_camera import PinholeCameraMetadata, PinholeIntrinsics
    from py123d.datatypes.time.timestamp import Timestamp
    from py123d.datatypes.vehicle_state.dynamic_state import DynamicStateSE3
    from py123d.datatypes.vehicle_state.ego_state import EgoStateSE3
    from py123d.datatypes.vehicle_state.ego_state_metadata import EgoStateSE3Metadata
    from py123d.geometry import BoundingBoxSE3, Polyline2D, PoseSE3, Vector3D
    from py123d.parser.base_dataset_parser import ModalitiesSync, ParsedCamera
    from py123d.parser.registry import NuPlanBoxDetectionLabel
except ModuleNotFoundError as err:  # py123d is installed apart, without its dependencies
    raise UserError(
        f"writing 123D logs needs py123d ({err}): pip install -e '.[py123d-writers]' "
        "&& pip install --no-deps 'py123d>=0.7,<0.8' (docs/datasets/py123d.md)"
    ) from None

from lead_s2r.geometry import CARLA_REAR_AXLE_TO_CENTER, points_to_local, rotate
from lead_s2r.synthetic import carla_lead as lead

STEP = 2  # 20 Hz ticks per 123D iteration: 10 Hz, LEAD's py123d_save_interval
LANE_HALF_WIDTH = 3.0  # wide enough for a 5 m car's front corner on the 10 m turn radius
REAR_AXLE_TO_IMU = (-0.4, 0.0, -0.3)  # write_log's rear axle in the IMU frame
LIDAR_HEIGHT = 2.5
CAMERA = {"width": 64, "height": 48, "f": 40.0}
NUPLAN_LABEL = {"car": NuPlanBoxDetectionLabel.VEHICLE, "walker": NuPlanBoxDetectionLabel.PEDESTRIAN}
LEAD_LABEL = {"car": DefaultBoxDetectionLabel.VEHICLE, "walker": DefaultBoxDetectionLabel.PERSON}
STATIC_LABEL = {"nuplan": NuPlanBoxDetectionLabel.TRAFFIC_CONE, "lead": DefaultBoxDetectionLabel.TRAFFIC_CONE}
#: map object ids of write_log's map: approach lane / group, turn connector / group, exit lane / group, intersection
LANES = {"approach": (1, 11), "turn": (2, 12), "exit": (3, 13)}
INTERSECTION_ID = 20
ONCOMING = 102  # carla_lead.make_actors' oncoming ambulance


def _pose(x: float, y: float, yaw: float, z: float = 0.0) -> PoseSE3:
    return PoseSE3(x, y, z, float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2)))


def iso(pose: np.ndarray) -> np.ndarray:
    """CARLA world (x, y, yaw) -> py123d's ISO world: y and yaw negated."""
    return np.asarray(pose, np.float64) * np.array([1.0, -1.0, -1.0])


def front_camera(name: str) -> PinholeCameraMetadata:
    """A small forward pinhole camera 1.5 m ahead of the IMU, 1.4 m up (optical axis = ego x)."""
    return PinholeCameraMetadata(
        camera_name=name,
        camera_id=CameraID.PCAM_F0,
        intrinsics=PinholeIntrinsics(CAMERA["f"], CAMERA["f"], CAMERA["width"] / 2, CAMERA["height"] / 2),
        distortion=None,
        width=CAMERA["width"],
        height=CAMERA["height"],
        camera_to_imu_se3=PoseSE3(1.5, 0.0, 1.4, 0.5, -0.5, 0.5, -0.5),
    )


def log_actors(actors: list[lead.Actor]) -> list[lead.Actor]:
    """write_log's actors: the CARLA scene's without the oncoming car, the walker standing (module docstring)."""
    return [replace(a, speed=0.0) if a.cls == "walker" else a for a in actors if a.actor_id != ONCOMING]


def jpeg(iteration: int) -> bytes:
    image = np.full((CAMERA["height"], CAMERA["width"], 3), 90, np.uint8)
    cv2.putText(image, str(iteration), (4, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2)
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 80])[1].tobytes()


def lidar_points(iteration: int) -> np.ndarray:
    """write_log's LiDAR at an iteration: a fixed fan of points in the IMU frame, shifted per frame."""
    angles = np.linspace(-np.pi, np.pi, 24, endpoint=False)
    return np.column_stack([10 * np.cos(angles) + 0.01 * iteration, 10 * np.sin(angles), np.full(24, 0.5)])


def _boxes(actors: list[lead.Actor], step: int, labels: dict, static: object, velocities: bool = True) -> list:
    """The actors' boxes at a 20 Hz tick in py123d's ISO world, world-frame velocities (None without ``velocities``)."""
    detections = []
    for actor in actors:
        if actor.cls == "traffic_light":
            continue  # neither nuPlan-style logs nor LEAD's exporter write traffic-light boxes
        pose = iso(actor.pose_at(np.array([step]))[0])
        heading = np.array([np.cos(pose[2]), np.sin(pose[2])]) * actor.speed
        length, width, height = (2 * e for e in actor.extent)
        detections.append(
            BoxDetectionSE3(
                BoxDetectionAttributes(labels.get(actor.cls, static), str(actor.actor_id)),
                BoundingBoxSE3(_pose(pose[0], pose[1], pose[2], actor.extent[2]), length, width, height),
                Vector3D(float(heading[0]), float(heading[1]), 0.0) if velocities else None,
            )
        )
    return detections


def _writer(root: Path, codec: str) -> ArrowLogWriter:
    config = LogWriterConfig(
        force_log_conversion=True, camera_store_option="jpeg_binary", lidar_store_option="binary", lidar_codec=codec
    )
    return ArrowLogWriter(log_writer_config=config, logs_root=root / "logs", sensors_root=root / "sensors")


def write_log(
    root: Path,
    name: str = "log-left",
    index: int = 0,
    frames: int = 12,
    seed: int = 0,
    codec: str = "ipc",
    dynamics: bool = True,
    box_velocities: bool = True,
) -> Path:
    """A nuPlan-style 123D log of the drive ``index`` (0 left turn, 1 right turn, 2 stop) and its map; returns the
    log folder (``root/logs/nuplan_test/<name>``). ``codec``: ipc | laz, the LiDAR payload; ``dynamics``: False
    writes poses only, as parsers of datasets without ego dynamics do; ``box_velocities``: False writes every box
    velocity null, as py123d's parsers of datasets without them (PandaSet) do."""
    drive, actors = lead.drive_and_actors(index, frames, np.random.default_rng(seed))
    actors = log_actors(actors)
    ego_meta = EgoStateSE3Metadata(
        vehicle_name="synthetic_suv",
        width=2.0,
        length=5.0,
        height=1.8,
        wheel_base=3.0,
        center_to_imu_se3=PoseSE3(1.1, 0.0, 0.4, 1.0, 0.0, 0.0, 0.0),
        rear_axle_to_imu_se3=PoseSE3(*REAR_AXLE_TO_IMU, 1.0, 0.0, 0.0, 0.0),
    )
    camera = front_camera("CAM_F0")
    lidar = LidarMetadata("MergedPointCloud", LidarID.LIDAR_TOP, PoseSE3(0.0, 0.0, LIDAR_HEIGHT, 1.0, 0.0, 0.0, 0.0))
    box_meta = BoxDetectionsSE3Metadata(box_detection_label_class=NuPlanBoxDetectionLabel)
    maps = MapMetadata(dataset="nuplan", location=f"synthetic-{name}", map_has_z=False, map_is_per_log=False)
    writer = _writer(root, codec)
    writer.reset(LogMetadata("nuplan", "nuplan_test", name, f"synthetic-{name}", maps))
    for step in range(0, len(drive.pose), STEP):
        ts = Timestamp.from_us(1_000_000 + step * 50_000)
        rear = iso(drive.pose[step])  # the drive's poses are taken as the rear axle here
        yaw_rate = -drive.yaw_rate[step]
        state = DynamicStateSE3(
            Vector3D(float(drive.speed[step]), 0.0, 0.0),
            Vector3D(float(drive.accel[step]), float(drive.speed[step] * yaw_rate), 0.0),
            Vector3D(0.0, 0.0, float(yaw_rate)),
        )
        ego = EgoStateSE3.from_rear_axle(_pose(*rear), ego_meta, ts, state if dynamics else None)
        red = drive.kind == "stop" or step < 10  # the turn's light turns green before the ego reaches it
        light = TrafficLightStatus.RED if red else TrafficLightStatus.GREEN
        modalities = [
            ego,
            BoxDetectionsSE3(_boxes(actors, step, NUPLAN_LABEL, STATIC_LABEL["nuplan"], box_velocities), ts, box_meta),
            ParsedCamera(camera, ts, None, byte_string=jpeg(step // STEP)),
            Lidar(ts, ts, lidar, lidar_points(step // STEP).astype(np.float32), _intensity(24)),
            TrafficLightDetections([TrafficLightDetection(LANES["turn"][0], light)], ts),
        ]
        writer.write_sync(ModalitiesSync(ts, modalities))
    writer.close()
    _write_map(root, maps, drive)
    return root / "logs" / "nuplan_test" / name


def _intensity(count: int) -> dict[str, np.ndarray]:
    return {LidarFeature.INTENSITY.serialize(): np.arange(count, dtype=np.uint8)}


def _lane_geometry(path: np.ndarray) -> tuple[Polyline2D, Polyline2D, Polyline2D]:
    """Left boundary, right boundary and centreline of a lane along ISO world poses (P, 3)."""
    normal = np.column_stack([-np.sin(path[:, 2]), np.cos(path[:, 2])]) * LANE_HALF_WIDTH
    centre = path[:, :2]
    return Polyline2D.from_array(centre + normal), Polyline2D.from_array(centre - normal), Polyline2D.from_array(centre)


def _write_map(root: Path, meta: MapMetadata, drive: lead.Drive) -> None:
    """Three lanes along the drive's path (approach, turn connector in an intersection, exit), each its own group."""
    path = iso(drive.path)
    cuts = {"approach": (0.0, lead.TURN_START), "turn": (lead.TURN_START, lead.TURN_END), "exit": (lead.TURN_END, None)}
    writer = ArrowMapWriter(force_map_conversion=True, maps_root=root / "maps", logs_root=root / "logs")
    writer.reset(meta)
    order = list(LANES)
    for k, name in enumerate(order):
        lane_id, group_id = LANES[name]
        start, end = cuts[name]
        first, last = round(start / 0.1), len(path) - 1 if end is None else round(end / 0.1)
        part = path[np.r_[np.arange(first, last, 5), last]]  # a point every 0.5 m; lanes meet end to start
        if name == "approach":  # begin 10 m behind the drive's start, so the ego's rear is on the map too
            back = part[0] - np.array([np.cos(part[0, 2]), np.sin(part[0, 2]), 0.0]) * 10.0
            part = np.vstack([back, part])
        left, right, centre = _lane_geometry(part)
        before = [LANES[order[k - 1]][0]] if k else []
        after = [LANES[order[k + 1]][0]] if k + 1 < len(order) else []
        group_before = [LANES[order[k - 1]][1]] if k else []
        group_after = [LANES[order[k + 1]][1]] if k + 1 < len(order) else []
        in_junction = INTERSECTION_ID if name == "turn" else None
        writer.write_map_object(
            Lane(lane_id, LaneType.SURFACE_STREET, left, right, centre, group_id, None, None, before, after, 10.0)
        )
        writer.write_map_object(LaneGroup(group_id, [lane_id], left, right, in_junction, group_before, group_after))
        if name == "turn":
            ring = np.vstack([left.array, right.array[::-1], left.array[:1]])
            writer.write_map_object(
                Intersection(INTERSECTION_ID, IntersectionType.TRAFFIC_LIGHT, [group_id], Polyline2D.from_array(ring))
            )
    writer.close()


def write_lead_log(root: Path, index: int = 0, frames: int = 12, seed: int = 0) -> Path:
    """The route ``carla_lead.write_route(root, index, frames, default_rng(seed))`` writes, as LEAD's 123D exporter
    logs it (module docstring); returns the log folder (``root/logs/carla_train/<name>``)."""
    drive, actors = lead.drive_and_actors(index, frames, np.random.default_rng(seed))
    ego_meta = EgoStateSE3Metadata(  # py123d's CARLA Lincoln, its centre at our CARLA rear-axle offset (docstring)
        vehicle_name="carla_lincoln_mkz_2020",
        width=1.83671,
        length=4.89238,
        height=1.49028,
        wheel_base=2.86048,
        center_to_imu_se3=PoseSE3(CARLA_REAR_AXLE_TO_CENTER, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0),
        rear_axle_to_imu_se3=PoseSE3.identity(),
    )
    lidar = LidarMetadata("LIDAR_TOP", LidarID.LIDAR_TOP, PoseSE3(0.0, 0.0, LIDAR_HEIGHT, 1.0, 0.0, 0.0, 0.0))
    box_meta = BoxDetectionsSE3Metadata(box_detection_label_class=DefaultBoxDetectionLabel)
    camera = front_camera("PCAM_F0")  # LEAD's exporter names its one camera by its id
    name = f"{lead.TOWNS[index % len(lead.TOWNS)]}_Rep0_{1000 + index}"
    maps = MapMetadata(dataset="carla", location="town12", map_has_z=True, map_is_per_log=False)
    writer = _writer(root, "laz")
    writer.reset(LogMetadata("carla", "carla_train", name, "town12", maps))
    for step in range(0, len(drive.pose), STEP):
        ts = Timestamp.from_us(step * 50_000)
        theta = drive.pose[step, 2]
        velocity = rotate(np.array([drive.speed[step], 0.0]), theta)  # CARLA world
        accel = rotate(np.array([drive.accel[step], drive.speed[step] * drive.yaw_rate[step]]), theta)
        dynamics = DynamicStateSE3(  # departure 1: world vectors (y negated), CARLA deg/s
            Vector3D(float(velocity[0]), float(-velocity[1]), 0.0),
            Vector3D(float(accel[0]), float(-accel[1]), 0.0),
            Vector3D(0.0, 0.0, float(np.rad2deg(drive.yaw_rate[step]))),
        )
        ego = EgoStateSE3.from_center(_pose(*iso(drive.pose[step])), ego_meta, ts, dynamics)
        points = lead_exported(lead_lidar(actors, drive.pose[step], step))
        modalities = [
            ego,
            BoxDetectionsSE3(_boxes(actors, step, LEAD_LABEL, STATIC_LABEL["lead"]), ts, box_meta),
            ParsedCamera(camera, ts, None, byte_string=jpeg(step // STEP)),
            Lidar(ts, ts, lidar, points.astype(np.float32), _intensity(len(points))),
            TrafficLightDetections([TrafficLightDetection(-1, TrafficLightStatus.RED)], ts),  # departure 2
        ]
        writer.write_sync(ModalitiesSync(ts, modalities))
    writer.close()
    return root / "logs" / "carla_train" / name


def lead_lidar(actors: list[lead.Actor], ego: np.ndarray, step: int) -> np.ndarray:
    """Points on the actors at a tick in LEAD's own LiDAR frame (CARLA vehicle centre, y right), as its route
    folders store them; the same for the same tick."""
    rng = np.random.default_rng(step)
    clouds = []
    for actor in actors:
        pose = actor.pose_at(np.array([step]))[0]
        local = rng.uniform(-1, 1, (20, 3)) * np.asarray(actor.extent)
        xy = rotate(local[:, :2], pose[2] - ego[2]) + points_to_local(pose[:2], ego)
        clouds.append(np.column_stack([xy, local[:, 2] + actor.extent[2]]))
    return np.concatenate(clouds)


def lead_exported(points: np.ndarray) -> np.ndarray:
    """Departure 3, as LEAD's exporter does it: y negated, x moved to the rear axle, z raised by half the height."""
    return np.column_stack([points[:, 0] + CARLA_REAR_AXLE_TO_CENTER, -points[:, 1], points[:, 2] + LIDAR_HEIGHT / 2])


def generate(out: Path, count: int | None = None, seed: int = 0) -> None:
    """``lead-s2r synth py123d --out DIR [--logs N]``: N nuPlan-style logs with their maps (default 3: left turn,
    right turn, stop) and one LEAD recording, under ``DIR/logs`` and ``DIR/maps``."""
    for index in range(3 if count is None else count):
        write_log(Path(out), f"log-{lead.KINDS[index % len(lead.KINDS)]}-{index}", index, frames=16, seed=seed)
    write_lead_log(Path(out), 0, frames=16, seed=seed)
