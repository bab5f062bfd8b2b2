"""A small NAVSIM / OpenScene dataset in the true on-disk layout, for round-trip tests and benchmarks.

Writes, under ``out``::

    navsim_logs/mini/<log>.pkl                       plain pickle: list of 28-key frame dicts at 2 Hz
    sensor_blobs/mini/<log>/CAM_*/<16hex>.jpg        8 cameras, 192x108 JPEGs (nuPlan's 1920x1080 / 10,
                                                     intrinsics scaled to match) rendered by :mod:`navsim_camera`
    sensor_blobs/mini/<log>/MergedPointCloud/<16hex>.pcd   binary PCD, fields x y z intensity ring lidar_info
    maps/us-nv-las-vegas-strip/9.15.1915/map.gpkg    the road network of :mod:`navsim_map`
    scene_filters/navmini.yaml                       NAVSIM SceneFilter yaml (log_names + tokens)
    scene_filters/pedestrians_ahead.yaml             the same, of the scenes of pedestrian logs (below)

Logs (2 Hz, 20 frames) are a competent driver's, so the logged human scores near the top of the PDM score, as
NAVSIM's human agent does on real logs: a straight drive in the right lane, a left turn through the traffic-lit
connector 2021 (red for frames 0-9, green after; connector 2012 has the opposite phase) taken at a turning speed
(yaw rate and lateral acceleration inside NAVSIM's comfort bounds) and entered only once it is green, and a slow
drive with an unknown command whose ``map_location`` is the legacy alias ``las_vegas``. Every log carries a lead
vehicle that the ego follows at a steady headway (it mirrors the ego's speed profile, :data:`TIME_GAP`), a
pedestrian and a traffic cone on the walkway to the right, a car parked in the car park, and a bicycle overtaking
in the other lane, seen only in frames 8-15: nothing overlaps the ego's path, so the logged trajectory has no
collision and a time to collision above NAVSIM's bound. Boxes are written the way OpenScene does: centres and yaw
in the ego frame of their frame, velocities rotated into the lidar frame.

Worlds where perception matters: in a third of the fresh logs (:func:`is_pedestrian_log`, straight routes only) a
group of pedestrians stands across the ego lane ahead instead of the lead vehicle, and the driver brakes smoothly to a
stop behind them (:mod:`~lead_s2r.synthetic.pedestrians_ahead`). The braking starts after the last scene's current frame
(:data:`BRAKE_AT`), and speed, acceleration and start are drawn as in the other logs, so no scene's ego status tells
the two kinds apart: only the cameras (the pedestrians are drawn in them) and the boxes do. A model that drives on
the status alone runs into them within its 4 s in the later scenes. NAVSIM's format has no field for such a label,
so the scenes are listed in a second scene filter, ``pedestrians_ahead.yaml``, which the adapter's ``tag_filters``
option turns into the tag ``scene_filter:pedestrians_ahead`` of each sample (docs/datasets/navsim.md).
"""

import math
import pickle
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import cv2
import numpy as np
import shapely
import yaml

from lead_s2r.files import write_bytes, write_text
from lead_s2r.geometry import homogeneous, rotate, to_local
from lead_s2r.synthetic import navsim_camera, navsim_map, pedestrians_ahead

DATA_SPLIT = "mini"
FRAMES = 20
DT_US = 500_000
HISTORY = 4
FUTURE = 10
IMAGE_SIZE = (192, 108)
FOCAL = 154.5
#: Camera name -> yaw of its optical axis in the lidar frame, degrees (counter-clockwise from forward).
CAMERAS = {"CAM_F0": 0, "CAM_L0": 55, "CAM_L1": 110, "CAM_L2": 150, "CAM_R0": -55, "CAM_R1": -110, "CAM_R2": -150}
CAMERAS["CAM_B0"] = 180
LIDAR2EGO_TRANSLATION = np.array([0.5, 0.0, 1.8])
LIDAR_POINTS = 2000
PCD_FIELDS = ("x", "y", "z", "intensity", "ring", "lidar_info")


@dataclass(frozen=True)
class LogSpec:
    """One synthetic log: the lanes it follows, its start along them, speed profile and command."""

    name: str
    lanes: tuple[int, ...]
    start: float
    speed: float
    accel: float
    command: tuple[int, int, int, int]
    map_location: str
    roadblocks: tuple[str, ...]
    #: seconds after frame 0 when the ego starts braking for the pedestrians ahead; None: no pedestrians ahead
    brake_at: float | None = None


#: Rear axle to front bumper of nuPlan's Pacifica, the ego NAVSIM's scorer simulates (m).
EGO_FRONT = 1.461 + 5.176 / 2
#: The lead vehicle's bumper-to-bumper gap at t = 0: STANDSTILL_GAP + TIME_GAP * speed (a two-second rule, longer
#: than PDM-Closed's IDM headway of 1.5 s, as a careful human keeps).
STANDSTILL_GAP = 2.0
TIME_GAP = 1.8
LEAD_SIZE = (4.6, 1.9, 1.6)
#: A left turn's speed (m/s): on the 12.25 m arc of connector 2021 a yaw rate of at most 0.53 rad/s and a lateral
#: acceleration of at most 3.5 m/s^2, inside NAVSIM's comfort bounds (0.95 rad/s, 4.89 m/s^2).
TURN_SPEED = (5.0, 6.5)
#: The left-turn connector, and the frame its light turns green (t = 5 s); a turning ego enters the connector after it.
LEFT_TURN = navsim_map.TRAFFIC_LIGHT_CONNECTORS[1]
GREEN_FRAME = 10

LOGS = (
    LogSpec(
        "2021.05.12.22.00.38_veh-35_01008_01518", (1011, 2011, 1021), 10.0, 8.0, 0.2, (0, 1, 0, 0),
        navsim_map.LOCATION, ("101", "201", "102"),
    ),
    LogSpec(
        "2021.06.07.18.53.26_veh-26_00005_00427", (1012, 2021, 1032), 65.0, 6.0, 0.0, (1, 0, 0, 0),
        navsim_map.LOCATION, ("101", "202", "103"),
    ),
    LogSpec(
        "2021.09.16.15.12.03_veh-42_01037_01434", (1011, 2011, 1021), 30.0, 3.0, 0.3, (0, 0, 0, 1),
        "las_vegas", ("101", "201", "102"),
    ),
)  # fmt: skip


@dataclass(frozen=True)
class Agent:
    """An object in local map coordinates moving at constant acceleration, seen in frames ``first..last``."""

    name: str
    xy: tuple[float, float]
    velocity: tuple[float, float]
    yaw: float
    size: tuple[float, float, float]
    first: int = 0
    last: int = FRAMES - 1
    accel: tuple[float, float] = (0.0, 0.0)

    def centre(self, t: float) -> np.ndarray:
        """(2,) centre at ``t`` seconds after frame 0."""
        return np.array(self.xy) + t * np.array(self.velocity) + 0.5 * t**2 * np.array(self.accel)

    def velocity_at(self, t: float) -> np.ndarray:
        return np.array(self.velocity) + t * np.array(self.accel)


#: Pedestrian logs start braking this many seconds after frame 0: after the last scene's current frame (4.5 s), so
#: every scene's ego status is a cruise's (:mod:`pedestrians_ahead`).
BRAKE_AT = (4.6, 5.4)
PEDESTRIAN_TAG = "pedestrians_ahead"


def lead_offset(speed: float) -> float:
    """How far the lead vehicle's centre is ahead of the ego's rear axle at t = 0 (m)."""
    return EGO_FRONT + STANDSTILL_GAP + TIME_GAP * speed + LEAD_SIZE[0] / 2


def agents_for(spec: LogSpec, start: np.ndarray) -> list[Agent]:
    """The objects around log ``spec`` whose ego starts at ``start`` heading east: the lead vehicle keeps its gap by
    driving the ego's speed profile (a turning ego leaves it going straight on). In a pedestrian log (``brake_at``),
    pedestrians stand across the lane ahead of where the ego stops instead of the lead vehicle."""
    x0, y0, speed, accel = float(start[0]), float(start[1]), spec.speed, spec.accel
    if spec.brake_at is None:
        ahead = [Agent("vehicle", (x0 + lead_offset(speed), y0), (speed, 0.0), 0.0, LEAD_SIZE, accel=(accel, 0.0))]
    else:
        stop = pedestrians_ahead.stopping_distance(speed, accel, spec.brake_at)
        x, size = x0 + pedestrians_ahead.row_distance(stop, EGO_FRONT), pedestrians_ahead.SIZE
        ahead = [Agent("pedestrian", (x, y0 + dy), (0.0, 0.0), math.pi / 2, size) for dy in pedestrians_ahead.ROW]
    return [
        *ahead,
        Agent("pedestrian", (x0 + 20.0, -4.5), (1.0, 0.0), 0.0, (0.6, 0.6, 1.8)),
        Agent("vehicle", (40.0, -10.0), (0.0, 0.0), math.pi / 2, (4.8, 2.0, 1.5)),
        Agent("traffic_cone", (x0 + 40.0, -3.9), (0.0, 0.0), 0.0, (0.4, 0.4, 0.7)),
        Agent("bicycle", (x0 - 10.0, -y0), (speed + 2.0, 0.0), 0.0, (1.8, 0.6, 1.5), first=8, last=15),
    ]


def route_line(lanes: tuple[int, ...]) -> shapely.LineString:
    """The ego's path: the centerlines of ``lanes`` joined end to end."""
    by_id = {lane.fid: lane for lane in navsim_map.LANES + navsim_map.LANE_CONNECTORS}
    points: list[tuple[float, float]] = []
    for fid in lanes:
        centerline = list(by_id[fid].centerline)
        points.extend(centerline[1:] if points and np.allclose(points[-1], centerline[0]) else centerline)
    return shapely.LineString(points)


def ego_states(spec: LogSpec) -> dict[str, np.ndarray]:
    """Poses (F,3) [x, y, yaw] in local map coordinates and ego-frame dynamics (F,4) [vx, vy, ax, ay]."""
    line = route_line(spec.lanes)
    t = np.arange(FRAMES) * DT_US / 1e6
    travelled, speed, accel = pedestrians_ahead.motion(spec.speed, spec.accel, spec.brake_at, t)
    s = spec.start + travelled

    def xy(at: np.ndarray) -> np.ndarray:
        return shapely.get_coordinates(shapely.line_interpolate_point(line, at))

    step = 0.05
    ahead, behind = xy(s + step), xy(s - step)
    yaw = np.arctan2(ahead[:, 1] - behind[:, 1], ahead[:, 0] - behind[:, 0])
    after = xy(s + 2 * step) - xy(s)
    before = xy(s) - xy(s - 2 * step)
    curvature = np.unwrap(np.arctan2(after[:, 1], after[:, 0]) - np.arctan2(before[:, 1], before[:, 0])) / (2 * step)
    dynamics = np.stack([speed, np.zeros_like(t), accel, speed**2 * curvature], axis=1)
    return {"poses": np.column_stack([xy(s), yaw]), "dynamics": dynamics}


def yaw_quaternion(yaw: float) -> np.ndarray:
    """[w, x, y, z] of a rotation about z."""
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def rot_z(yaw: float) -> np.ndarray:
    cos, sin = math.cos(yaw), math.sin(yaw)
    return np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])


#: Optical frame (x right, y down, z forward) -> lidar frame (x forward, y left, z up) of a front camera.
OPTICAL_TO_FORWARD = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def camera_calibration(name: str) -> dict[str, np.ndarray]:
    """sensor2lidar rotation/translation, intrinsics and distortion of one camera."""
    yaw = math.radians(CAMERAS[name])
    rotation = rot_z(yaw) @ OPTICAL_TO_FORWARD
    translation = rot_z(yaw) @ np.array([1.0, 0.0, -0.3])
    width, height = IMAGE_SIZE
    intrinsic = np.array([[FOCAL, 0.0, width / 2], [0.0, FOCAL, height / 2], [0.0, 0.0, 1.0]])
    distortion = np.array([-0.35, 0.15, 0.0005, -0.0002, -0.03])
    return {
        "sensor2lidar_rotation": rotation,
        "sensor2lidar_translation": translation,
        "cam_intrinsic": intrinsic,
        "distortion": distortion,
    }


@lru_cache(maxsize=len(CAMERAS))
def camera(name: str) -> navsim_camera.Camera:
    """Camera ``name`` as :mod:`navsim_camera` renders through it (its calibration, on the ego)."""
    calib = camera_calibration(name)
    origin = LIDAR2EGO_TRANSLATION + calib["sensor2lidar_translation"]  # the lidar frame is not rotated here
    return navsim_camera.Camera(
        calib["cam_intrinsic"], calib["distortion"], calib["sensor2lidar_rotation"], origin, IMAGE_SIZE
    )


def render_camera(name: str, pose: np.ndarray, anns: dict[str, np.ndarray], rng: np.random.Generator) -> np.ndarray:
    """Camera ``name``'s image of an ego at the local map pose ``pose`` among the boxes of ``anns``."""
    return navsim_camera.render(camera(name), pose, anns["gt_boxes"], list(anns["gt_names"]), rng)


def write_jpeg(path: Path, image: np.ndarray) -> None:
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok, path
    write_bytes(path, data.tobytes())


def write_pcd(path: Path, points: np.ndarray) -> None:
    """nuPlan's binary PCD v0.7: a text header, then float32 records of the 6 fields."""
    n = len(points)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(PCD_FIELDS)}\nSIZE 4 4 4 4 4 4\nTYPE F F F F F F\nCOUNT 1 1 1 1 1 1\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    write_bytes(path, header.encode("ascii") + points.astype("<f4").tobytes())


def lidar_points(rng: np.random.Generator) -> np.ndarray:
    """(N, 6) points in the lidar frame: x, y, z, intensity, ring, lidar id."""
    n = LIDAR_POINTS
    xyz = [rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), rng.uniform(-2.0, 1.0, n)]
    return np.column_stack([*xyz, rng.integers(0, 256, n), rng.integers(0, 64, n), rng.integers(0, 5, n)])


def annotations(agents: list[Agent], frame: int, pose: np.ndarray, tokens: list[str]) -> dict[str, np.ndarray]:
    """OpenScene ``anns`` of the agents seen in ``frame``, in the ego frame at ``pose``."""
    t = frame * DT_US / 1e6
    boxes, names, velocities, tracks = [], [], [], []
    for agent, token in zip(agents, tokens, strict=True):
        if not agent.first <= frame <= agent.last:
            continue
        x, y, yaw = to_local(np.r_[agent.centre(t), agent.yaw], pose)
        length, width, height = agent.size
        boxes.append([x, y, height / 2, length, width, height, yaw])
        velocity = rotate(agent.velocity_at(t), -pose[2])  # the lidar frame is not rotated against the ego's here
        velocities.append([velocity[0], velocity[1], 0.0])
        names.append(agent.name)
        tracks.append(token)
    return {
        "gt_boxes": np.array(boxes, dtype=np.float64).reshape(-1, 7),
        "gt_names": np.array(names),
        "gt_velocity_3d": np.array(velocities, dtype=np.float64).reshape(-1, 3),
        "instance_tokens": np.array([token[::-1] for token in tracks]),
        "track_tokens": np.array(tracks),
    }


def traffic_lights(frame: int) -> list[tuple[int, bool]]:
    """Connector 2021 (left turn) is red before :data:`GREEN_FRAME`, connector 2012 from it on."""
    straight = navsim_map.TRAFFIC_LIGHT_CONNECTORS[0]
    return [(straight, frame >= GREEN_FRAME), (LEFT_TURN, frame < GREEN_FRAME)]


def _hex(rng: np.random.Generator) -> str:
    return rng.bytes(8).hex()


def write_log(
    out: Path, spec: LogSpec, rng: np.random.Generator, logs: Path | None = None, blobs: Path | None = None
) -> list[dict]:
    """Write one log's sensor blobs and pickle (under ``logs`` and ``blobs``, by default the ``mini`` split's
    ``navsim_logs`` and ``sensor_blobs`` folders of ``out``); return its frames."""
    logs = out / "navsim_logs" / DATA_SPLIT if logs is None else logs
    blobs = out / "sensor_blobs" / DATA_SPLIT if blobs is None else blobs
    states = ego_states(spec)
    poses, dynamics = states["poses"], states["dynamics"]
    agents = agents_for(spec, poses[0])
    track_tokens = [_hex(rng) for _ in agents]
    tokens = [_hex(rng) for _ in range(FRAMES)]
    lidar2ego = homogeneous(np.eye(3), LIDAR2EGO_TRANSLATION)
    start_us = 1_620_856_838_000_000 + int(rng.integers(0, 10**9))
    frames = []
    for i in range(FRAMES):
        x, y, yaw = poses[i, 0] + navsim_map.ORIGIN[0], poses[i, 1] + navsim_map.ORIGIN[1], poses[i, 2]
        translation, quaternion = np.array([x, y, 0.0]), yaw_quaternion(yaw)
        ego2global = homogeneous(rot_z(yaw), translation)
        vx, vy, ax, ay = dynamics[i]
        can_bus = np.zeros(18)
        can_bus[0:3], can_bus[3:7], can_bus[7:9], can_bus[13:15] = translation, quaternion, (ax, ay), (vx, vy)
        anns, cams = annotations(agents, i, poses[i], track_tokens), {}
        for name in CAMERAS:
            blob = f"{spec.name}/{name}/{_hex(rng)}.jpg"
            write_jpeg(blobs / blob, render_camera(name, poses[i], anns, rng))
            cams[name] = {"data_path": blob, **camera_calibration(name)}
        lidar_path = f"{spec.name}/MergedPointCloud/{_hex(rng)}.pcd"
        write_pcd(blobs / lidar_path, lidar_points(rng))
        frames.append(
            {
                "token": tokens[i],
                "frame_idx": i,
                "timestamp": start_us + i * DT_US,
                "log_name": spec.name,
                "log_token": spec.name.encode().hex()[:16],
                "scene_name": f"scene-{spec.name[-11:]}",
                "scene_token": tokens[0][::-1],
                "map_location": spec.map_location,
                "roadblock_ids": list(spec.roadblocks),
                "vehicle_name": spec.name.split("_")[1],
                "can_bus": can_bus,
                "lidar_path": lidar_path,
                "lidar2ego_translation": LIDAR2EGO_TRANSLATION.copy(),
                "lidar2ego_rotation": np.array([1.0, 0.0, 0.0, 0.0]),
                "ego2global_translation": translation,
                "ego2global_rotation": quaternion,
                "ego2global": ego2global,
                "lidar2ego": lidar2ego,
                "lidar2global": ego2global @ lidar2ego,
                "ego_dynamic_state": [float(vx), float(vy), float(ax), float(ay)],
                "traffic_lights": traffic_lights(i),
                "driving_command": np.array(spec.command, dtype=np.int64),
                "cams": cams,
                "sample_prev": tokens[i - 1] if i > 0 else None,
                "sample_next": tokens[i + 1] if i + 1 < FRAMES else None,
                "anns": anns,
                "occ_gt_final_path": None,
                "flow_gt_final_path": None,
            }
        )
    write_bytes(logs / f"{spec.name}.pkl", pickle.dumps(frames, protocol=pickle.HIGHEST_PROTOCOL))
    return frames


def scene_filter(
    logs: dict[str, list[dict]], tokens: list[str], history: int = HISTORY, future: int = FUTURE, **extra: object
) -> dict[str, object]:
    """A NAVSIM ``SceneFilter`` config over ``logs`` selecting ``tokens`` (``extra`` keys appended)."""
    return {
        "_target_": "navsim.common.dataclasses.SceneFilter",
        "_convert_": "all",
        "num_history_frames": history,
        "num_future_frames": future,
        "frame_interval": 1,
        "has_route": True,
        "max_scenes": None,
        **extra,
        "log_names": list(logs),
        "tokens": tokens,
    }


def write_scene_filter(path: Path, logs: dict[str, list[dict]]) -> None:
    """A NAVSIM SceneFilter yaml listing every scene of ``logs`` with a full history and future."""
    tokens = [frames[i]["token"] for frames in logs.values() for i in range(HISTORY - 1, FRAMES - FUTURE)]
    write_text(path, yaml.safe_dump(scene_filter(logs, tokens), sort_keys=False))


@dataclass(frozen=True)
class Ranges:
    """What a fresh log on a base log's route draws uniformly: speed (m/s), acceleration (m/s^2) and, on a straight
    route, its start as an offset from the base log's (m); a turning log's start follows from its speed."""

    speed: tuple[float, float]
    accel: tuple[float, float]
    start: tuple[float, float] = (-10.0, 10.0)


#: Per base log of :data:`LOGS`: a cruise below the 13.4 m/s limit, a turn at turning speed, a slow drive.
RANGES = (Ranges((6.0, 10.5), (-0.3, 0.3)), Ranges(TURN_SPEED, (0.0, 0.0)), Ranges((2.0, 5.0), (0.0, 0.4)))
#: When a turning log's front bumper reaches connector 2021 (s after frame 0): after the light turns green, and
#: soon enough that the turn falls in the scenes' futures.
TURN_ENTRY = (GREEN_FRAME * DT_US / 1e6 + 0.2, 7.0)


def turn_start(speed: float, entry: float) -> float:
    """Where on the route (m) an ego at constant ``speed`` starts so that its front bumper reaches the end of lane
    1012 (x = 100), where connector 2021 begins, ``entry`` seconds later."""
    return navsim_map.JUNCTION_X - EGO_FRONT - speed * entry


def is_pedestrian_log(index: int) -> bool:
    """Whether fresh log ``index`` has pedestrians ahead: one cruise and one slow drive in every six logs (a third
    of the logs, half of those on straight routes), so every split of consecutive logs holds its share."""
    return index >= len(LOGS) and index % 6 in (3, 5)


def log_specs(count: int | None, seed: int = 0) -> list[LogSpec]:
    """``count`` logs (default 3): :data:`LOGS`, then fresh logs cycling over their routes, each drawing its speed,
    acceleration and start from its route's :data:`RANGES` (so held-out logs look like training logs); a pedestrian
    log (:func:`is_pedestrian_log`) draws the same, then when it brakes (:data:`BRAKE_AT`)."""
    count = len(LOGS) if count is None else count
    specs = list(LOGS[:count])
    for i in range(len(LOGS), count):
        base, ranges, rng = LOGS[i % len(LOGS)], RANGES[i % len(LOGS)], np.random.default_rng([seed, i])
        speed, accel = float(rng.uniform(*ranges.speed)), float(rng.uniform(*ranges.accel))
        offset = float(rng.uniform(*ranges.start))
        start = turn_start(speed, float(rng.uniform(*TURN_ENTRY))) if LEFT_TURN in base.lanes else base.start + offset
        brake_at = float(rng.uniform(*BRAKE_AT)) if is_pedestrian_log(i) else None
        name = f"{base.name[:-11]}{i:05d}_{i + 1:05d}"
        specs.append(replace(base, name=name, start=start, speed=speed, accel=accel, brake_at=brake_at))
    return specs


def generate(out: Path, count: int | None = None, seed: int = 0, splits: dict[str, int] | None = None) -> None:
    """Write the dataset described in the module docstring with ``count`` logs (default 3) in the ``mini`` split, or
    with ``splits`` (split folder -> logs, e.g. ``{"trainval": 12, "test": 4}``) the logs of :func:`log_specs` dealt
    out to those folders in order, so every split holds logs of one distribution (pedestrian logs included)."""
    out = Path(out)
    rng = np.random.default_rng(seed)
    navsim_map.write_map(out / "maps")
    splits = splits or {DATA_SPLIT: len(LOGS) if count is None else count}
    specs = iter(log_specs(sum(splits.values()), seed))
    logs, pedestrian_logs = {}, {}
    for split, logs_in_split in splits.items():
        for spec in (next(specs) for _ in range(logs_in_split)):
            logs[spec.name] = write_log(out, spec, rng, out / "navsim_logs" / split, out / "sensor_blobs" / split)
            if spec.brake_at is not None:
                pedestrian_logs[spec.name] = logs[spec.name]
    write_scene_filter(out / "scene_filters" / "navmini.yaml", logs)
    write_scene_filter(out / "scene_filters" / f"{PEDESTRIAN_TAG}.yaml", pedestrian_logs)
