"""PDM-Closed, the rule-based planner whose trajectory normalises NAVSIM's ego progress (EP).

NAVSIM plans it once per scene at metric-caching time (``MetricCacheProcessor``): 3 paths (the route centreline and
its +-1 m parallels) x 5 IDM policies (0.2..1.0 x the start lane's speed limit, 15 m/s without one) are unrolled for
4 s at 10 Hz against constant-velocity forecasts of the t = 0 objects and red lights on the route, simulated and
scored with the PDM scorer (EP normalised over all 15), and the best is unrolled on to 5 s. Sources read for the
facts: tuplan_garage / navsim ``pdm_generator.py``, ``batch_idm_policy.py``, ``pdm_observation.py``,
``pdm_object_manager.py``, ``pdm_path.py``, ``abstract_pdm_closed_planner.py``. Behaviours reproduced on purpose:

* the IDM acceleration exponent is 10 and the acceleration is clipped to [-d_max, a_max];
* the leading agent is searched every 2nd step and copied in between; at step 1 the copy is the all-zero row of
  step 0 (a lead at progress 0), so an already moving ego brakes for the first 0.1 s;
* leads are objects whose forecast polygon intersects the path corridor (the path's vertices between the ego's
  start progress and + v_max * 5 s, buffered by half the ego width with square caps) and whose centroid projects
  ahead of the ego; the gap is the footprint-to-polygon distance, the lead speed |v| cos(heading difference) of the
  t = 0 object (0 for static objects); with no lead the path's end is one at half an ego length. The leader row is
  carried from one proposal of a path to the next and only partly rewritten (a leader leaves the rear length, a
  red light the speed, free road the speed of the previous proposal in place);
* forecasts move every 0.2 s (the observation keeps every 2nd 10 Hz step), objects farther than 100 m from the ego
  centre are dropped, at most 50 vehicles, 25 pedestrians, 10 bicycles and 50 static objects nearest the ego
  centre are kept, and an agent moving backwards is forecast along its heading + pi;
* objects overlapping the ego footprint at t = 0 (and red-light lane connectors containing it) are ignored
  throughout, which is what NAVSIM's ``collided_track_ids`` does;
* path poses are interpolated linearly in progress with the heading unwrapped, progress clipped to
  [1e-5, length]; the plan is the IDM path poses, not the simulated states.
"""

from dataclasses import dataclass, field

import numpy as np
import shapely
import shapely.ops

from lead_s2r.geometry import wrap_angle
from lead_s2r.schema import BoxClass, MapKind
from lead_s2r.scoring.pdm.observation import dense_observation
from lead_s2r.scoring.pdm.route import ego_footprint, ego_footprints, pose_boxes
from lead_s2r.scoring.pdm.scene import PDMScene, ragged_polygons
from lead_s2r.scoring.pdm.score import score_states
from lead_s2r.scoring.pdm.simulation import simulate_proposals
from lead_s2r.scoring.pdm.vehicle import VehicleParameters

#: nuPlan's AGENT_TYPES among our box classes: forecast with their velocity; the rest are static objects.
AGENT_CLASSES = (BoxClass.VEHICLE, BoxClass.PEDESTRIAN, BoxClass.BICYCLE)
#: PDMObjectManager caps: nearest objects kept per class (static objects share one cap).
MAX_OBJECTS = {BoxClass.VEHICLE: 50, BoxClass.PEDESTRIAN: 25, BoxClass.BICYCLE: 10}
MAX_STATIC_OBJECTS = 50


@dataclass(frozen=True)
class PDMClosedConfig:
    """NAVSIM's ``MetricCacheProcessor`` PDM-Closed settings."""

    lateral_offsets: tuple[float, ...] = (-1.0, 1.0)
    speed_limit_fractions: tuple[float, ...] = (0.2, 0.4, 0.6, 0.8, 1.0)
    fallback_target_velocity: float = 15.0
    min_gap: float = 1.0
    headway_time: float = 1.5
    accel_max: float = 1.5
    decel_max: float = 3.0
    acceleration_exponent: float = 10.0
    interval: float = 0.1
    proposal_steps: int = 40
    trajectory_steps: int = 50
    leading_agent_update: int = 2
    observation_resolution: int = 2
    map_radius: float = 100.0


class PDMPath:
    """A discrete path (L, 3): cumulative progress, a linestring, and poses at any progress."""

    def __init__(self, points: np.ndarray) -> None:
        self.points = np.asarray(points, np.float64).copy()
        self.points[:, 2] = np.unwrap(self.points[:, 2])
        steps = np.linalg.norm(np.diff(self.points[:, :2], axis=0), axis=1)
        self.progress = np.concatenate([[0.0], np.cumsum(steps)])
        self.linestring = shapely.LineString(self.points[:, :2])

    @property
    def length(self) -> float:
        return float(self.progress[-1])

    def interpolate(self, distance: np.ndarray) -> np.ndarray:
        """Poses (..., 3) at progress ``distance`` (clipped to [1e-5, length]), heading wrapped."""
        distance = np.clip(np.asarray(distance, np.float64), 1e-5, self.length)
        out = np.stack([np.interp(distance, self.progress, self.points[:, i]) for i in range(3)], axis=-1)
        out[..., 2] = np.arctan2(np.sin(out[..., 2]), np.cos(out[..., 2]))
        return out

    def project(self, points: np.ndarray) -> np.ndarray:
        """Progress of the nearest path point to each (..., 2) point."""
        return shapely.line_locate_point(self.linestring, shapely.points(np.asarray(points, np.float64)))

    def substring(self, start: float, end: float) -> shapely.LineString:
        """The path's vertices with progress in [start, end] (shapely's substring when fewer than 2)."""
        start, end = np.clip([start, end], 0.0, self.length)
        inside = (start <= self.progress) & (self.progress <= end)
        if inside.sum() > 1:
            return shapely.LineString(self.points[inside, :2])
        return shapely.ops.substring(self.linestring, start, end)


def offset_path(points: np.ndarray, offset: float) -> np.ndarray:
    """The parallel path ``offset`` metres to the left (negative: right) of a discrete path (L, 3)."""
    points = np.asarray(points, np.float64)
    normal = points[:, 2] + np.pi / 2
    return np.column_stack(
        [points[:, 0] + offset * np.cos(normal), points[:, 1] + offset * np.sin(normal), points[:, 2]]
    )


def idm_step(
    progress: np.ndarray,
    velocity: np.ndarray,
    lead: np.ndarray,
    target_velocity: np.ndarray,
    config: PDMClosedConfig = PDMClosedConfig(),
) -> tuple[np.ndarray, np.ndarray]:
    """One Euler step of the batched IDM: ``lead`` (N, 3) is (progress, velocity, rear length) of the leader."""
    lead_progress, lead_velocity, lead_rear = lead[:, 0], lead[:, 1], lead[:, 2]
    desired_gap = (
        config.min_gap
        + velocity * config.headway_time
        + velocity * (velocity - lead_velocity) / (2 * np.sqrt(config.accel_max * config.decel_max))
    )
    gap = np.maximum(lead_progress - progress - lead_rear, config.min_gap)
    with np.errstate(divide="ignore", invalid="ignore"):
        free = (velocity / target_velocity) ** config.acceleration_exponent
    acceleration = config.accel_max * (1 - free - (desired_gap / gap) ** 2)
    acceleration = np.clip(acceleration, -config.decel_max, config.accel_max)
    return progress + config.interval * velocity, velocity + config.interval * acceleration


@dataclass
class Forecast:
    """Constant-velocity forecasts of the t = 0 objects at every 10 Hz step, and the red lights on the route."""

    poses: np.ndarray  # (M, S, 3)
    velocity: np.ndarray  # (M, S, 2)
    size: np.ndarray  # (M, 3)
    agent_class: np.ndarray  # (M,)
    speed: np.ndarray  # (M,) |v| at t = 0 (0 for static objects)
    heading: np.ndarray  # (M,) heading at t = 0
    red_lights: list[shapely.Polygon]
    built: dict[int, np.ndarray] = field(default_factory=dict, repr=False)

    def polygons(self, step: int) -> np.ndarray:
        """Object polygons at 10 Hz step ``step``, then the red lights (which never move); built once per step."""
        if step not in self.built:
            moving = agent_box_polygons(self.poses[:, step], self.size)
            self.built[step] = np.concatenate([moving, np.array(self.red_lights, object)])
        return self.built[step]

    def lead_speed(self, index: np.ndarray, ego_heading: np.ndarray) -> np.ndarray:
        """Speed of objects (indices into :meth:`polygons`) along the ego headings; 0 for red lights."""
        out = np.zeros(len(index))
        objects = index < len(self.speed)
        chosen = index[objects]
        out[objects] = self.speed[chosen] * np.cos(wrap_angle(self.heading[chosen] - ego_heading[objects]))
        return out


def agent_box_polygons(poses: np.ndarray, size: np.ndarray) -> np.ndarray:
    """Shapely boxes of centre poses (M, 3) with (length, width, ...) sizes (M, 2+)."""
    half = np.asarray(size, np.float64)[:, None, :2] / 2 * np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]])
    return pose_boxes(poses, half)


def select_objects(scene: PDMScene, config: PDMClosedConfig = PDMClosedConfig()) -> np.ndarray:
    """Rows of the objects PDM-Closed sees at t = 0: within the map radius of the ego centre, the nearest per
    class up to the caps (static objects first, then agents by class), less those overlapping the ego footprint."""
    centre = np.array([scene.vehicle.rear_axle_to_center, 0.0])
    seen = np.flatnonzero(scene.agent_valid[:, 0])
    distance = np.linalg.norm(scene.agent_poses[seen, 0, :2] - centre, axis=1)
    seen, distance = seen[distance <= config.map_radius], distance[distance <= config.map_radius]
    classes = scene.agent_class[seen]
    static = np.flatnonzero(~np.isin(classes, [int(c) for c in AGENT_CLASSES]))
    chosen = [seen[static[np.argsort(distance[static])][:MAX_STATIC_OBJECTS]]]
    for label, cap in MAX_OBJECTS.items():
        rows = np.flatnonzero(classes == label)
        chosen.append(seen[rows[np.argsort(distance[rows])][:cap]])
    rows = np.concatenate(chosen).astype(np.int64)
    overlapping = shapely.intersects(
        agent_box_polygons(scene.agent_poses[rows, 0], scene.agent_size[rows]),
        ego_footprint(np.zeros(3), scene.vehicle),
    )
    return rows[~overlapping]


def forecast(scene: PDMScene, config: PDMClosedConfig = PDMClosedConfig()) -> Forecast:
    """:class:`Forecast` of ``scene`` over ``trajectory_steps + 1`` steps (objects move every 0.2 s)."""
    rows = select_objects(scene, config)
    pose = scene.agent_poses[rows, 0].astype(np.float64)
    velocity = scene.agent_velocity[rows, 0].astype(np.float64)
    is_agent = np.isin(scene.agent_class[rows], [int(c) for c in AGENT_CLASSES])
    speed = np.where(is_agent, np.linalg.norm(velocity, axis=1), 0.0)
    backwards = np.abs(wrap_angle(pose[:, 2] - np.arctan2(velocity[:, 1], velocity[:, 0]))) >= np.pi / 2
    direction = pose[:, 2] + np.where(backwards, np.pi, 0.0)
    dxy = speed[:, None] * np.column_stack([np.cos(direction), np.sin(direction)])
    steps = np.arange(config.trajectory_steps + 1)
    elapsed = (steps // config.observation_resolution) * config.observation_resolution * config.interval
    poses = np.repeat(pose[:, None], len(steps), axis=1)
    poses[..., :2] += dxy[:, None] * elapsed[None, :, None]
    return Forecast(
        poses=poses,
        velocity=np.repeat(dxy[:, None], len(steps), axis=1),
        size=scene.agent_size[rows].astype(np.float64),
        agent_class=scene.agent_class[rows],
        speed=speed,
        heading=pose[:, 2],
        red_lights=red_lights_at_start(scene),
    )


def red_lights_at_start(scene: PDMScene) -> list[shapely.Polygon]:
    """Polygons of on-route lane connectors red at t = 0, except one containing the ego footprint."""
    if len(scene.red_light_offsets) < 2:  # no traffic-light keyframes
        return []
    red = set(scene.red_light_ids[scene.red_light_offsets[0] : scene.red_light_offsets[1]].tolist())
    on_route = red & set(scene.route_lane_ids.tolist())
    wanted = (scene.polygon_kind == MapKind.LANE_CONNECTOR) & np.isin(scene.polygon_id, list(on_route))
    if not wanted.any():
        return []
    polygons = ragged_polygons(scene.polygon_xy, scene.polygon_offsets)[wanted]
    footprint = ego_footprint(np.zeros(3), scene.vehicle)
    return [polygon for polygon in polygons if not shapely.within(footprint, polygon)]


@dataclass
class Unroll:
    """IDM states (N, S + 1, 2) of progress and velocity, path poses (N, S + 1, 3), leaders (N, S + 1, 3), filled
    up to step ``done``."""

    idm: np.ndarray
    poses: np.ndarray
    lead: np.ndarray
    done: int = 0


def _leaders(
    path: PDMPath,
    corridor: shapely.Geometry,
    observation: Forecast,
    step: int,
    progress: np.ndarray,
    poses: np.ndarray,
    vehicle: VehicleParameters,
) -> np.ndarray:
    """Leader (progress, velocity, rear length) for proposals at ``progress`` with rear-axle ``poses`` (N, 3), one
    row carried through the proposals of a path and only partly rewritten, as NAVSIM's (module docstring)."""
    found = np.zeros(len(progress), bool)
    gap, speed, red = np.zeros(len(progress)), np.zeros(len(progress)), np.zeros(len(progress), bool)
    polygons = observation.polygons(step)
    hits = np.flatnonzero(shapely.intersects(polygons, corridor))
    if len(hits):
        object_progress = path.project(shapely.get_coordinates(shapely.centroid(polygons[hits])))
        ahead = object_progress[None, :] > progress[:, None]  # (N, H)
        rows = np.flatnonzero(ahead.any(axis=1))
        if len(rows):
            distance = shapely.distance(ego_footprints(poses[rows], vehicle)[:, None], polygons[hits][None, :])
            distance = np.where(ahead[rows], distance, np.inf)
            nearest = np.argmin(distance, axis=1)
            found[rows] = True
            gap[rows] = distance[np.arange(len(rows)), nearest]
            speed[rows] = observation.lead_speed(hits[nearest], poses[rows, 2])
            red[rows] = hits[nearest] >= len(observation.speed)
    lead = np.zeros((len(progress), 3))
    row = np.zeros(3)
    for n in range(len(progress)):
        if found[n]:
            row[0] = progress[n] + gap[n]
            row[1] = row[1] if red[n] else speed[n]
        else:
            row[0], row[2] = path.length, vehicle.length / 2
        lead[n] = row
    return lead


def corridor(path: PDMPath, start: float, distance: float, width: float) -> shapely.Geometry:
    """The path ahead of ``start`` for ``distance`` metres, buffered by half the ego ``width`` (square caps)."""
    return shapely.buffer(path.substring(start, start + distance), width / 2, cap_style="square")


def unroll(
    path: PDMPath,
    target_velocity: np.ndarray,
    initial_velocity: float,
    observation: Forecast,
    steps: int,
    vehicle: VehicleParameters,
    config: PDMClosedConfig = PDMClosedConfig(),
    max_target_velocity: float | None = None,
    state: Unroll | None = None,
) -> Unroll:
    """Unroll IDM policies (one per ``target_velocity``) along ``path`` up to ``steps``, continuing ``state``."""
    total = config.trajectory_steps + 1
    if state is None:
        start = float(path.project(np.zeros(2)))
        state = Unroll(np.zeros((len(target_velocity), total, 2)), np.zeros((len(target_velocity), total, 3)),
                       np.zeros((len(target_velocity), total, 3)))  # fmt: skip
        state.idm[:, 0] = (start, initial_velocity)
        state.poses[:, 0] = path.interpolate(start)
    v_max = abs(max(target_velocity) if max_target_velocity is None else max_target_velocity)
    area = corridor(path, state.idm[0, 0, 0], v_max * config.trajectory_steps * config.interval, vehicle.width)
    for step in range(state.done + 1, steps + 1):
        if step % config.leading_agent_update:
            state.lead[:, step] = state.lead[:, step - 1]
        else:
            state.lead[:, step] = _leaders(
                path, area, observation, step, state.idm[:, step - 1, 0], state.poses[:, step - 1], vehicle
            )
        progress, velocity = idm_step(
            state.idm[:, step - 1, 0], state.idm[:, step - 1, 1], state.lead[:, step], target_velocity, config
        )
        state.idm[:, step] = np.column_stack([progress, velocity])
        state.poses[:, step] = path.interpolate(progress)
    state.done = max(state.done, steps)
    return state


def target_velocities(speed_limit: float, config: PDMClosedConfig = PDMClosedConfig()) -> np.ndarray:
    """The IDM policies' target speeds: fractions of the speed limit, of the fallback where there is none."""
    limit = speed_limit if np.isfinite(speed_limit) else config.fallback_target_velocity
    return np.asarray(config.speed_limit_fractions) * limit


def plan_reference(scene: PDMScene, config: PDMClosedConfig = PDMClosedConfig()) -> np.ndarray:
    """PDM-Closed's trajectory for ``scene``: (51, 3) ego-frame rear-axle poses at 0.1 s from t = 0."""
    observation = forecast(scene, config)
    paths = [PDMPath(scene.centerline)] + [PDMPath(offset_path(scene.centerline, o)) for o in config.lateral_offsets]
    targets = target_velocities(scene.speed_limit_mps, config)
    speed = float(scene.ego_velocity[0])
    unrolled = [
        unroll(path, targets, speed, observation, config.proposal_steps, scene.vehicle, config) for path in paths
    ]
    proposals = np.concatenate([u.poses[:, : config.proposal_steps + 1] for u in unrolled])
    states = simulate_proposals(
        proposals, scene.ego_velocity, scene.ego_acceleration, scene.tire_steering_angle, scene.vehicle
    )
    steps = observation.poses.shape[1]
    dense = dense_observation(
        observation.poses,
        observation.velocity,
        np.ones(observation.poses.shape[:2], bool),
        observation.size,
        observation.agent_class,
        red_light_polygons=[observation.red_lights] * steps,
    )
    scores = score_states(scene, states, dense, None)["score"]
    best = int(np.argmax(scores))
    lateral, longitudinal = divmod(best, len(targets))
    state = unrolled[lateral]
    pick = slice(longitudinal, longitudinal + 1)
    chosen = Unroll(state.idm[pick].copy(), state.poses[pick].copy(), state.lead[pick].copy(), state.done)
    final = unroll(
        paths[lateral],
        targets[longitudinal : longitudinal + 1],
        speed,
        observation,
        config.trajectory_steps,
        scene.vehicle,
        config,
        max_target_velocity=float(max(targets)),
        state=chosen,
    )
    return final.poses[0]
