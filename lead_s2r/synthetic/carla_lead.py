"""Write tiny LEAD CARLA route folders in the expert's true on-disk format (see ``docs/datasets/carla_lead.md``).

Each route is a short, physically plausible drive in CARLA's left-handed world (x forward, y right, yaw clockwise): a
left turn, a right turn, or a stop, cycled over the routes. The stop is the scene that needs perception in the synthetic
NAVSIM and WOD-E2E worlds too (:mod:`~lead_s2r.synthetic.pedestrians_ahead`): a row of walkers stands across the ego
lane, labelled as ``walker`` boxes and drawn in the front tile of the camera mosaic, and the expert brakes to a
standstill behind them (``walker_hazard``), so LTFv6 + LEAD gets CARLA's perception labels of the object kind that the
real-data worlds test. Written as the LEAD expert writes it: 4 Hz frames of a 20 Hz simulation, LZMA-compressed pickles
for metas and boxes (ego-centre frame, y right), a JPEG camera mosaic at q=30 plus a perturbated-rig twin, 1/4-scale
8-bit depth, 256x256 hdmap at 2 px/m, LAZ LiDAR with a ``time`` extra dimension and float16 radar npz files.

The mosaic follows the route's camera rig (``dataset_information.target_dataset``,
:data:`~lead_s2r.synthetic.carla_lead_sensors.RIG_MOSAICS`), one of LEAD's: 3-camera (1152x384, the default), 6-camera
(2304x384), single wide camera (1024x384, the top 384 of 512 rows) and NAVSIM-matched (1920x270, top 270 of 280 rows).

Frames are light by default (five actors, about 700 LiDAR points, two target-point planners), which keeps tests
fast. ``realistic=True`` writes frames as heavy as LEAD's (for loader benchmarks): a street of about 60 actors
within the 96 m box radius, each mover with its 2 s future; the LiDAR file holding 5 motion-compensated sweeps of
non-ground points plus 10 steps of radar returns duplicated 5x within 32 m, as LEAD's expert stacks them (about
60,000 points, :data:`~lead_s2r.synthetic.carla_lead_sensors.REALISTIC_LIDAR`); full 75-point radar clouds per
sensor; and metas with every planner LEAD saves (pop distances 3.00..10.00 m by 0.25, GNSS twins). Where the counts
come from: docs/benchmarks.md.
"""

import json
import lzma
import pickle
import pickletools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from lead_s2r.geometry import points_to_local, resample, to_global, wrap_angle
from lead_s2r.synthetic import carla_lead_sensors as sensors
from lead_s2r.synthetic import pedestrians_ahead

SAVE_FREQ = 5
DT = 1.0 / sensors.FPS
EGO_FUTURE_STEPS = 60
OTHER_FUTURE_STEPS = 40
PAST_STEPS = 60
TP_DISTANCES = (3.0, 3.25)
#: LEAD's ``tp_distances``: one route planner per pop distance, each saved with a GNSS twin (realistic frames).
REALISTIC_TP_DISTANCES = tuple(3.0 + 0.25 * k for k in range(29))
DEFAULT_TP_DISTANCE = 7.5
ROUTE_POINTS = 50
TURN_RADIUS = 10.0
TURN_START = 8.0
TURN_END = TURN_START + np.pi / 2 * TURN_RADIUS
DEFAULT_RIG = "CARLA_LEADERBOARD2_3CAMERAS"
JPEG_QUALITY = 30
EGO_EXTENT = (2.4508416652679443, 1.0641621351242065, 0.7553732395172119)

# CARLA RoadOption codes as the expert stores them.
LEFT, RIGHT, STRAIGHT, LANEFOLLOW = 1, 2, 3, 4
KINDS = ("left", "right", "stop")
SCENARIOS = {"left": "SignalizedJunctionLeftTurn", "right": "SignalizedJunctionRightTurn", "stop": "PedestrianCrossing"}
#: The stop's expert: cruise speed (m/s), when it brakes (s) and how hard (m/s^2); it stands still after
#: STOP_SPEED * BRAKE_AT + STOP_SPEED^2 / (2 STOP_DECEL) metres.
STOP_SPEED, BRAKE_AT, STOP_DECEL = 7.0, 0.5, 3.5
#: The blueprint of the walkers the stop brakes for (the mosaic draws these).
WALKER_AHEAD = "walker.pedestrian.0015"
TOWNS = ("Town12", "Town13", "Town10HD")
#: LEAD's ``TransfuserSemanticSegmentationClass`` id the expert stores with each box (``transfuser_semantics_id``).
TRANSFUSER_SEMANTICS = {"car": 1, "traffic_light": 3, "walker": 4, "static": 6}


@dataclass
class Drive:
    """The ego's 20 Hz world trajectory and the geometric path it follows (arc length -> pose)."""

    kind: str
    pose: np.ndarray  # (S, 3) world x, y, theta
    speed: np.ndarray  # (S,)
    accel: np.ndarray  # (S,) longitudinal
    yaw_rate: np.ndarray  # (S,) CARLA sign: positive turns right
    arc: np.ndarray  # (S,) arc length travelled
    path: np.ndarray  # (P, 3) world poses every 0.1 m of arc length
    plan: list[tuple[float, int]]  # (arc length, RoadOption) of the sparse global plan


def _curvature(kind: str, s: np.ndarray) -> np.ndarray:
    """Signed curvature along the path; a left turn is negative in CARLA's clockwise-yaw convention."""
    turning = (s >= TURN_START) & (s < TURN_END)
    sign = {"left": -1.0, "right": 1.0, "stop": 0.0}[kind]
    return np.where(turning, sign / TURN_RADIUS, 0.0)


def _integrate_path(kind: str, start: np.ndarray, length: float, ds: float = 0.1) -> np.ndarray:
    """World poses every ``ds`` metres of the route centreline (midpoint rule, exact on arcs to 1e-6 m)."""
    s = np.arange(0.0, length + ds, ds)
    theta = start[2] + np.concatenate([[0.0], np.cumsum(_curvature(kind, s[:-1] + ds / 2) * ds)])
    mid = (theta[:-1] + theta[1:]) / 2
    x = start[0] + np.concatenate([[0.0], np.cumsum(np.cos(mid) * ds)])
    y = start[1] + np.concatenate([[0.0], np.cumsum(np.sin(mid) * ds)])
    return np.stack([x, y, theta], axis=1)


def _speed_profile(kind: str, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Speed and longitudinal acceleration at 20 Hz: cruise through turns, brake to a standstill for a stop."""
    t = np.arange(steps) * DT
    if kind != "stop":
        return np.full(steps, 6.0), np.zeros(steps)
    speed = np.clip(STOP_SPEED - STOP_DECEL * np.clip(t - BRAKE_AT, 0.0, None), 0.0, None)
    accel = np.where((t >= BRAKE_AT) & (speed > 0), -STOP_DECEL, 0.0)
    return speed, accel


def make_drive(kind: str, steps: int, rng: np.random.Generator) -> Drive:
    """Simulate the ego along its route for ``steps`` 20 Hz ticks."""
    speed, accel = _speed_profile(kind, steps)
    s = np.concatenate([[0.0], np.cumsum((speed[:-1] + speed[1:]) / 2 * DT)])
    start = np.array([rng.uniform(-200, 200), rng.uniform(-200, 200), rng.uniform(-np.pi, np.pi)])
    path = _integrate_path(kind, start, s[-1] + ROUTE_POINTS + 40.0)
    pose, _ = resample(np.arange(len(path)) * 0.1, path, s, angle_columns=(2,))
    yaw_rate = _curvature(kind, s) * speed
    if kind == "stop":
        plan = [(10.0 * i, STRAIGHT if i == 2 else LANEFOLLOW) for i in range(int(path_len(path) // 10))]
    else:
        option = LEFT if kind == "left" else RIGHT
        plan = [(0.0, LANEFOLLOW), (TURN_START, option), ((TURN_START + TURN_END) / 2, option), (TURN_END, LANEFOLLOW)]
        plan += [(d, LANEFOLLOW) for d in np.arange(TURN_END + 10.0, path_len(path), 10.0)]
    return Drive(kind, pose, speed, accel, yaw_rate, s, path, plan)


def path_len(path: np.ndarray) -> float:
    return (len(path) - 1) * 0.1


def write_pickle(path: Path, obj: object) -> None:
    """LEAD's ``write_pickle``: an optimised pickle inside an LZMA stream, despite the ``.pkl`` name."""
    with lzma.open(path, "wb") as file:
        file.write(pickletools.optimize(pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)))


class _Planner:
    """A route planner popping global-plan points once the ego is within ``distance`` of the next one."""

    def __init__(self, points: np.ndarray, commands: list[int], distance: float) -> None:
        self.points, self.commands, self.distance = list(points), list(commands), distance
        self.popped: list[tuple[np.ndarray, int]] = []

    def step(self, position: np.ndarray) -> None:
        while len(self.points) > 1 and np.hypot(*(self.points[1][:2] - position[:2])) < self.distance:
            self.popped.append((self.points.pop(0), self.commands.pop(0)))

    def state(self, suffix: str, source: str = "") -> dict[str, list]:
        """The planner's meta keys, e.g. ``next_target_points_3.25``; ``source="_gps"`` names its GNSS twin."""
        last = self.popped[-1:]
        return {
            f"next{source}_target_points{suffix}": [p.tolist() for p in self.points],
            f"next{source}_commands{suffix}": list(self.commands),
            f"previous{source}_target_points{suffix}": [p.tolist() for p, _ in last],
            f"previous{source}_commands{suffix}": [c for _, c in last],
        }


@dataclass
class Actor:
    """Another road user moving at constant velocity in the world, or a static object."""

    cls: str
    actor_id: int
    type_id: str
    extent: tuple[float, float, float]
    start: np.ndarray  # world x, y, yaw
    speed: float

    def pose_at(self, step: np.ndarray) -> np.ndarray:
        t = np.asarray(step, np.float64) * DT
        x = self.start[0] + self.speed * t * np.cos(self.start[2])
        y = self.start[1] + self.speed * t * np.sin(self.start[2])
        return np.stack([x, y, np.full_like(t, self.start[2])], -1)


def walkers_ahead(at: Callable[[float, float], np.ndarray]) -> list[Actor]:
    """The stop's row of walkers across the ego lane, ``GAP`` ahead of where the expert's front bumper stops
    (``at(s, lateral)``: the route's world pose ``s`` metres along it, ``lateral`` to the side)."""
    stop = STOP_SPEED * BRAKE_AT + STOP_SPEED**2 / (2 * STOP_DECEL)
    distance = pedestrians_ahead.row_distance(stop, EGO_EXTENT[0])  # the ego's reference is its centre
    length, width, height = pedestrians_ahead.SIZE
    extent, across = (length / 2, width / 2, height / 2), np.array([0.0, 0.0, np.pi / 2])
    return [
        Actor("walker", 210 + i, WALKER_AHEAD, extent, at(distance, lateral) + across, 0.0)
        for i, lateral in enumerate(pedestrians_ahead.ROW)
    ]


def make_actors(drive: Drive, rng: np.random.Generator) -> list[Actor]:
    """A car ahead in the ego's lane (a stop: walkers across it instead), an oncoming car, a crossing pedestrian, a
    cone and a traffic light."""

    def at(s: float, lateral: float) -> np.ndarray:
        pose = drive.path[int(s / 0.1)]
        return pose + np.array([-np.sin(pose[2]) * lateral, np.cos(pose[2]) * lateral, 0.0])

    car = at(14.0, 0.0)
    oncoming = at(30.0, -3.5) + np.array([0.0, 0.0, np.pi])
    walker = at(20.0, 6.0) + np.array([0.0, 0.0, -np.pi / 2])
    ahead = [Actor("car", 101, "vehicle.lincoln.mkz_2020", (2.45, 1.06, 0.76), car, 5.0 + rng.uniform(0, 1))]
    return [
        *(walkers_ahead(at) if drive.kind == "stop" else ahead),
        Actor("car", 102, "vehicle.ford.ambulance", (3.2, 1.2, 1.2), oncoming, 4.0),
        Actor("walker", 201, "walker.pedestrian.0012", (0.3, 0.3, 0.9), walker, 1.2),
        Actor("static", 301, "static.prop.trafficcone01", (0.2, 0.2, 0.4), at(6.0, 2.5), 0.0),
        Actor("traffic_light", 401, "traffic.traffic_light", (0.3, 0.3, 1.5), at(19.0, 3.0), 0.0),
    ]


def drive_and_actors(index: int, frames: int, rng: np.random.Generator) -> tuple[Drive, list[Actor]]:
    """Route ``index``'s drive (its kind cycles over :data:`KINDS`) for ``frames`` 4 Hz frames, and its actors."""
    drive = make_drive(KINDS[index % len(KINDS)], (frames - 1) * SAVE_FREQ + EGO_FUTURE_STEPS + 1, rng)
    return drive, make_actors(drive, rng)


#: Realistic frames: the actors of a busy street, as (class, type_id, extent, lateral offsets from the route in m,
#: speed range m/s, count). Moving cars use both lanes, parked cars and walkers the kerbs.
STREET = (
    ("car", "vehicle.tesla.model3", (2.4, 1.05, 0.75), (-5.25, -1.75, 1.75), (3.0, 10.0), 22),
    ("car", "vehicle.audi.a2", (1.85, 0.9, 0.77), (-8.0, 8.0), (0.0, 0.0), 12),
    ("walker", "walker.pedestrian.0001", (0.3, 0.3, 0.9), (-11.0, 11.0), (0.8, 1.6), 12),
    ("traffic_light", "traffic.traffic_light", (0.3, 0.3, 1.5), (-7.0, 7.0), (0.0, 0.0), 6),
    ("static", "static.prop.trafficcone01", (0.2, 0.2, 0.4), (-7.5, 7.5), (0.0, 0.0), 8),
)


def make_street(drive: Drive, rng: np.random.Generator) -> list[Actor]:
    """:data:`STREET`'s actors scattered along the route (realistic frames); ids from 1000."""
    actors = []
    for cls, type_id, extent, laterals, (v0, v1), count in STREET:
        for _ in range(count):
            pose = drive.path[rng.integers(len(drive.path))]
            lateral = float(rng.choice(laterals))
            start = pose + np.array([-np.sin(pose[2]) * lateral, np.cos(pose[2]) * lateral, 0.0])
            if lateral < 0:  # the oncoming lane and the far kerb face the other way
                start[2] += np.pi
            actors.append(Actor(cls, 1000 + len(actors), type_id, extent, start, float(rng.uniform(v0, v1))))
    return actors


def _matrix(pose: np.ndarray) -> list[list[float]]:
    """4x4 world transform of a planar pose, as CARLA's ``get_matrix`` gives it."""
    matrix = np.eye(4)
    matrix[:2, :2] = [[np.cos(pose[2]), -np.sin(pose[2])], [np.sin(pose[2]), np.cos(pose[2])]]
    matrix[:2, 3] = pose[:2]
    return matrix.tolist()


def _box(actor: Actor, ego: np.ndarray, step: int) -> dict:
    pose = actor.pose_at(np.array([step]))[0]
    rel = points_to_local(pose[:2], ego)
    box = {
        "class": actor.cls,
        "extent": list(actor.extent),
        "position": [float(rel[0]), float(rel[1]), float(actor.extent[2])],
        "yaw": float(wrap_angle(pose[2] - ego[2])),
        "speed": actor.speed,
        "id": actor.actor_id,
        "type_id": actor.type_id,
        "distance": float(np.hypot(*rel)),
        "matrix": _matrix(pose),
        "transfuser_semantics_id": TRANSFUSER_SEMANTICS[actor.cls],
    }
    if actor.cls == "traffic_light":  # the expert counts no LiDAR hits or pixels on traffic lights
        box.update(state="Green", affects_ego=True, same_lane_as_ego=True)
        return box
    box["num_points"] = 40
    if actor.cls == "static":  # nor pixels on static props other than parked cars
        box["mesh_path"] = "/Game/Carla/Static/TrafficCone/SM_TrafficCone.SM_TrafficCone"
        return box
    box["visible_pixels"] = 500
    future = actor.pose_at(step + np.arange(OTHER_FUTURE_STEPS + 1))
    box.update(
        brake=False,
        num_radar_points=3,
        role_name="scenario" if actor.cls == "car" else "walker",
        lane_type_str="Driving",
        base_type="car" if actor.cls == "car" else "",
        future_positions=points_to_local(future[:, :2], ego).astype(np.float16),
        future_yaws=wrap_angle(future[:, 2] - ego[2]).astype(np.float16),
    )
    return box


def _ego_box(speed: float) -> dict:
    return {
        "class": "ego_car",
        "extent": list(EGO_EXTENT),
        "position": [0.0, 0.0, 0.0],
        "yaw": 0.0,
        "speed": speed,
        "brake": False,
        "id": 1,
        "matrix": np.eye(4).tolist(),
    }


def _meta(drive: Drive, step: int, planners: dict[str, _Planner], extras: dict, rig: str) -> dict:
    ego = drive.pose[step]
    future = drive.pose[step : step + EGO_FUTURE_STEPS + 1]
    past = drive.pose[max(step - PAST_STEPS, 0) : step + 1][::-1]
    s_now = float(drive.arc[step])
    route_s = s_now + 2.5 + np.arange(ROUTE_POINTS)
    route_world = drive.path[np.minimum((route_s / 0.1).round().astype(int), len(drive.path) - 1)]
    meta = {
        "pos_global": [float(ego[0]), float(ego[1]), 0.0],
        "theta": float(ego[2]),
        "ego_matrix": _matrix(ego),
        "speed": float(drive.speed[step]),
        "accel_x": float(drive.accel[step]),
        "accel_y": float(drive.speed[step] * drive.yaw_rate[step]),
        "accel_z": 9.81,
        "angular_velocity_x": 0.0,
        "angular_velocity_y": 0.0,
        "angular_velocity_z": float(drive.yaw_rate[step]),
        "target_speed": 0.0 if drive.kind == "stop" and drive.speed[step] < 3 else 6.0,
        "steer": float(np.clip(drive.yaw_rate[step] / 2, -1, 1)),
        "throttle": 0.3 if drive.accel[step] >= 0 and drive.speed[step] > 0 else 0.0,
        "brake": bool(drive.accel[step] < 0 or drive.speed[step] == 0),
        "route": points_to_local(route_world[:, :2], ego).astype(np.float32),
        "changed_route": False,
        "future_positions": np.column_stack([points_to_local(future[:, :2], ego), np.zeros(len(future))]),
        "future_yaws": wrap_angle(future[:, 2] - ego[2]),
        "future_speeds": drive.speed[step : step + EGO_FUTURE_STEPS + 1].copy(),
        "past_positions": np.column_stack([points_to_local(past[:, :2], ego), np.zeros(len(past))]),
        "past_yaws": wrap_angle(past[:, 2] - ego[2]),
        "past_speeds": drive.speed[max(step - PAST_STEPS, 0) : step + 1][::-1].copy(),
        "stop_sign_hazard": False,
        "light_hazard": False,
        "walker_hazard": drive.kind == "stop",
        "vehicle_hazard": False,
        "dist_to_junction": None,
        "is_junction": TURN_START < s_now < TURN_END and drive.kind != "stop",
        "scenario_obstacles_ids": [],
        "vehicle_opened_door": False,
        "vehicle_door_side": None,
        "over_head_traffic_light": False,
        "europe_traffic_light": False,
        "dataset_information": {
            "save_depth_resolution_ratio": sensors.DEPTH_RATIO,
            "save_depth_bits": 8,
            "target_dataset": rig,
            "data_save_freq": SAVE_FREQ,
        },
        **extras,
    }
    for distance, planner in planners.items():
        meta.update(planner.state("" if distance == DEFAULT_TP_DISTANCE else f"_{distance}"))
        if len(planners) > len(TP_DISTANCES) + 1:  # realistic frames: LEAD saves a GNSS twin of every planner
            meta.update(planner.state("" if distance == DEFAULT_TP_DISTANCE else f"_{distance}", "_gps"))
    return meta


def write_route(
    root: Path, index: int, frames: int, rng: np.random.Generator, rig: str = DEFAULT_RIG, realistic: bool = False
) -> Path:
    """One route folder with ``frames`` 4 Hz frames and every LEAD sensor folder, cameras of camera rig ``rig``;
    ``realistic``: frames as heavy as LEAD's (module docstring)."""
    kind = KINDS[index % len(KINDS)]
    town = TOWNS[index % len(TOWNS)]
    route_id = 1000 + index
    folder = root / "data" / SCENARIOS[kind] / f"{town}_Rep0_{route_id}_route0_01_10_05_46_{index % 60:02d}"
    rigs = [
        f"{sensor}{twin}" for sensor in ("rgb", "semantics", "depth", "hdmap", "radar") for twin in ("", "_perturbated")
    ]
    for name in (*rigs, "lidar", "bboxes", "metas"):  # one LiDAR for both rigs, as LEAD records it
        (folder / name).mkdir(parents=True, exist_ok=True)
    drive, actors = drive_and_actors(index, frames, rng)
    actors += make_street(drive, rng) if realistic else []
    translation = float(rng.choice([-1, 1]) * rng.uniform(0.1, 1.0))
    rotation = float(-np.sign(translation) * (5.0 + (abs(translation) - 0.1) / 0.9 * 7.5))
    view = np.array([0.0, translation, np.deg2rad(rotation)])  # the perturbated rig's pose in the ego frame
    plan_s, commands = zip(*drive.plan, strict=True)
    plan_points = np.column_stack([drive.path[(np.array(plan_s) / 0.1).round().astype(int), :2], np.zeros(len(plan_s))])
    distances = REALISTIC_TP_DISTANCES if realistic else TP_DISTANCES
    planners = {d: _Planner(plan_points, commands, d) for d in (*distances, DEFAULT_TP_DISTANCE)}
    extras = {
        "town": town,
        "scenario": SCENARIOS[kind],
        "weather_setting": "ClearNoon",
        "weather_parameters": {"cloudiness": 5.0, "precipitation": 0.0, "sun_altitude_angle": 45.0},
        "jpeg_storage_quality": JPEG_QUALITY,
        "perturbation_translation": translation,
        "perturbation_rotation": rotation,
    }
    for step in range((frames - 1) * SAVE_FREQ + 1):
        for planner in planners.values():
            planner.step(drive.pose[step])
        if step % SAVE_FREQ:
            continue
        frame = step // SAVE_FREQ
        name = f"{frame:04d}"
        ego = drive.pose[step]
        boxes = [_ego_box(float(drive.speed[step]))] + [_box(actor, ego, step) for actor in actors]
        walkers = np.array([box["position"][:2] for box in boxes if box.get("type_id") == WALKER_AHEAD])
        write_pickle(folder / "bboxes" / f"{name}.pkl", boxes)
        write_pickle(folder / "metas" / f"{name}.pkl", _meta(drive, step, planners, extras, rig))
        for suffix, shift, pose in (("", 0.0, ego), ("_perturbated", translation, to_global(view, ego))):
            mosaic = sensors.mosaic(rig, frame, shift, rng, walkers)
            jpeg = cv2.imencode(".jpg", mosaic, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])[1]
            (folder / f"rgb{suffix}" / f"{name}.jpg").write_bytes(jpeg.tobytes())
            cv2.imwrite(str(folder / f"semantics{suffix}" / f"{name}.png"), sensors.semantics(rig))
            cv2.imwrite(str(folder / f"depth{suffix}" / f"{name}.png"), sensors.depth(rig, frame))
            cv2.imwrite(str(folder / f"hdmap{suffix}" / f"{name}.png"), sensors.hdmap(drive.path, pose))
        if realistic:
            points, times = sensors.dense_lidar_points(boxes, float(drive.speed[step]), rng)
        else:
            points, times = sensors.lidar_points(boxes, rng)
        sensors.write_laz(folder / "lidar" / f"{name}.laz", points, times)
        radar = sensors.radar(boxes, rng, realistic)
        np.savez_compressed(folder / "radar" / f"{name}.npz", **radar)
        view_radar = {key: points_to_local(cloud, view).astype(np.float16) for key, cloud in radar.items()}
        np.savez_compressed(folder / "radar_perturbated" / f"{name}.npz", **view_radar)
    results = {
        "index": index,
        "route_id": f"{route_id}",
        "status": "Completed",
        "num_infractions": 0,
        "infractions": {"collisions_vehicle": [], "min_speed_infractions": [], "outside_route_lanes": []},
        "scores": {"score_route": 100.0, "score_penalty": 1.0, "score_composed": 100.0},
        "meta": {"route_length": float(path_len(drive.path)), "duration_game": len(drive.pose) * DT},
    }
    (folder / "results.json").write_text(json.dumps(results, indent=2))
    return folder


def generate(
    out: Path,
    count: int | None = None,
    seed: int = 0,
    frames: int = 16,
    rigs: tuple[str, ...] = (DEFAULT_RIG,),
    realistic: bool = False,
) -> None:
    """Write ``count`` routes (default 3: left turn, right turn, stop) under ``out/data/<Scenario>/<route>/``,
    cycling through the camera ``rigs`` (names of :data:`~lead_s2r.synthetic.carla_lead_sensors.RIG_MOSAICS`);
    ``realistic``: frames as heavy as LEAD's."""
    unknown = set(rigs) - set(sensors.RIG_MOSAICS)
    if unknown:
        raise ValueError(f"unknown camera rigs {sorted(unknown)}; known: {', '.join(sensors.RIG_MOSAICS)}")
    rng = np.random.default_rng(seed)
    for index in range(3 if count is None else count):
        write_route(Path(out), index, frames, rng, rigs[index % len(rigs)], realistic)
