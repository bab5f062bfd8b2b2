"""The agents the PDM score checks the ego against: their box polygons at every 10 Hz step.

``log_observation`` rebuilds NAVSIM v1.1's ``MetricCacheProcessor._interpolate_gt_observation`` from the 2 Hz
keyframes; ``dense_observation`` takes boxes already at 10 Hz (PDM-Closed's constant-velocity forecasts). Official
behaviours reproduced on purpose:

* Interpolation is scipy ``interp1d``'s linear formula (``slope * (t - t_lo) + y_lo``, ``t_lo`` found with a left
  ``searchsorted``) on x, y, the ``np.unwrap``-ed heading, vx and vy over the keyframes that see the track; the
  heading is wrapped back with ``arctan2(sin, cos)``. A track exists at ``t`` only for ``first <= t <= last`` seen
  time (gaps between sightings are bridged).
* A track seen in a single keyframe is inserted unchanged (its own heading and velocity) at every step.
* The box size is the first sighting's; static classes (cone, barrier, sign, generic object) carry zero velocity.
* The object a collision is classified with (nuPlan's ``unique_objects``) is the track's *first* 10 Hz appearance:
  the "track stopped" test of NC reads the speed there, not the speed at the time of the collision.
* Red-light pseudo-objects (EPDMS, PDM-Closed) live among the same per-step boxes and are skipped by NC and TTC.

Constants: v1.1 keyframes every 0.5 s up to 5 s, 51 steps of 0.1 s (TTC looks 0.9 s past the 4 s horizon).
v2.2 reads the 9 keyframes up to 4 s and builds 41 steps (``extend_observation_for_ttc=False``), and its log replay
(``LogReplayTrafficAgents.simulate_environment``) drops from every step each track whose box intersects the ego box
at t0 (its step-0 box, so a track seen once at a later keyframe counts with that box). v1.1 removes nothing.

NAVSIM keeps one STRtree per step; NC and TTC here find candidate pairs by enclosing circles (``collisions``).
"""

from dataclasses import dataclass

import numpy as np
import shapely

from lead_s2r.schema import BoxClass
from lead_s2r.scoring.pdm.footprint import box_coords, box_polygons
from lead_s2r.scoring.pdm.interpolation import interp1d
from lead_s2r.scoring.pdm.overlap import Axes
from lead_s2r.scoring.pdm.scene import PDMScene
from lead_s2r.scoring.pdm.vehicle import VehicleParameters

#: nuPlan ``AGENT_TYPES`` (a nuPlan ``Agent`` rather than a ``StaticObject``); an emergency vehicle is a vehicle.
AGENT_CLASSES = (BoxClass.VEHICLE, BoxClass.PEDESTRIAN, BoxClass.BICYCLE, BoxClass.EMERGENCY_VEHICLE)
#: Observation steps of NAVSIM v1.1 (0..5 s at 10 Hz) and v2.2 (0..4 s).
V11_STEPS = 51
V2_STEPS = 41
STEP_S = 0.1
#: Tolerance [s] when comparing keyframe times with the horizon.
KEYFRAME_SLACK_S = 1e-6


@dataclass
class Observation:
    """G box polygons over all steps, step by step, each with the radius of a circle about its centroid that holds
    it. Objects are the M tracks followed by red-light pseudo-objects; per-object arrays describe the first one."""

    polygons: np.ndarray  # (G,) shapely Polygons
    corners: np.ndarray  # (G, 4, 2) a box's corners in ring order (NaN for red-light polygons)
    axes: Axes  # the corners' separating axes and extents, computed once for every NC/TTC query that meets a box
    objects: np.ndarray  # (G,) int64 object index
    centroids: np.ndarray  # (G, 2)
    radius: np.ndarray  # (G,)
    step_offsets: np.ndarray  # (S + 1,) geometries of step s are [step_offsets[s], step_offsets[s + 1])
    step_geoms: np.ndarray  # (S, Gmax) geometry index, -1 pads
    object_is_agent: np.ndarray  # (O,) nuPlan Agent (moving kind) rather than static object
    object_speed: np.ndarray  # (O,) speed at the first appearance
    object_is_red_light: np.ndarray  # (O,)

    @property
    def num_steps(self) -> int:
        return len(self.step_offsets) - 1


def interpolate_keyframes(
    keyframe_t: np.ndarray,
    poses: np.ndarray,
    velocity: np.ndarray,
    valid: np.ndarray,
    is_agent: np.ndarray,
    num_steps: int = V11_STEPS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keyframe tracks ``(M, T, ...)`` at 10 Hz: poses ``(M, S, 3)``, velocity ``(M, S, 2)``, valid ``(M, S)``."""
    query_times = np.arange(0, num_steps, 1, dtype=float) * STEP_S
    num_tracks = len(poses)
    out_poses = np.zeros((num_tracks, num_steps, 3))
    out_velocity = np.zeros((num_tracks, num_steps, 2))
    out_valid = np.zeros((num_tracks, num_steps), bool)
    for m in range(num_tracks):
        seen = np.flatnonzero(valid[m])
        track_velocity = velocity[m, seen] if is_agent[m] else np.zeros((len(seen), 2))
        if len(seen) == 1:
            out_poses[m], out_velocity[m], out_valid[m] = poses[m, seen[0]], track_velocity[0], True
        elif len(seen) > 1:
            times = keyframe_t[seen].astype(np.float64)
            inside = (times[0] <= query_times) & (query_times <= times[-1])
            states = interp1d(times, np.concatenate([poses[m, seen], track_velocity], -1), query_times[inside])
            states[:, 2] = np.arctan2(np.sin(states[:, 2]), np.cos(states[:, 2]))
            out_poses[m, inside], out_velocity[m, inside], out_valid[m] = states[:, :3], states[:, 3:], inside
    return out_poses, out_velocity, out_valid


def _step_layout(step_of: np.ndarray, num_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets ``(S + 1,)`` and the padded ``(S, Gmax)`` index table of geometries sorted by step."""
    step_offsets = np.searchsorted(step_of, np.arange(num_steps + 1))
    rank = np.arange(len(step_of)) - step_offsets[step_of]
    step_geoms = np.full((num_steps, int(np.diff(step_offsets).max(initial=0))), -1, np.int64)
    step_geoms[step_of, rank] = np.arange(len(step_of))
    return step_offsets, step_geoms


def _enclosing_radius(polygons: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """Per polygon the largest distance from its centroid to a vertex: a circle that holds the polygon."""
    coords, index = shapely.get_coordinates(polygons, return_index=True)
    radius = np.zeros(len(polygons))
    np.maximum.at(radius, index, np.hypot(*(coords - centroids[index]).T))
    return radius


def log_observation(scene: PDMScene, num_steps: int = V11_STEPS, replay: bool = False) -> Observation:
    """The logged agents of ``scene`` at 10 Hz, as NAVSIM's metric cache builds them (v1.1: 51 steps). Only
    keyframes up to the last step's time are read, as NAVSIM samples keyframes up to its horizon (v1.1 5 s, v2 4 s
    with ``num_steps=41``): "seen once" and the first/last sighting are counted within that horizon. ``replay``:
    v2.2's log replay, without the tracks that overlap the ego at t0 (:func:`overlapping_ego_at_t0`)."""
    keyframe_t = np.asarray(scene.agent_t, np.float64)
    within = keyframe_t <= (num_steps - 1) * STEP_S + KEYFRAME_SLACK_S
    is_agent = np.isin(scene.agent_class, AGENT_CLASSES)
    poses, velocity, valid = interpolate_keyframes(
        keyframe_t[within],
        scene.agent_poses[:, within],
        scene.agent_velocity[:, within],
        scene.agent_valid[:, within],
        is_agent,
        num_steps,
    )
    if replay:
        valid = valid & ~overlapping_ego_at_t0(poses[:, 0], valid[:, 0], scene.agent_size, scene.vehicle)[:, None]
    return dense_observation(poses, velocity, valid, scene.agent_size, scene.agent_class)


def overlapping_ego_at_t0(
    poses: np.ndarray, present: np.ndarray, size: np.ndarray, vehicle: VehicleParameters
) -> np.ndarray:
    """``(M,)``: tracks present at step 0 whose box (centre poses ``(M, 3)``, size ``(M, 3)``) intersects the ego box
    at t0 (rear axle at the origin, heading 0)."""
    size = np.asarray(size, np.float64).reshape(-1, 3)
    ego = box_coords(np.array([vehicle.rear_axle_to_center, 0.0]), np.zeros(()), vehicle.length, vehicle.width)
    boxes = box_coords(poses[:, :2], poses[:, 2], size[:, 0], size[:, 1])
    return present & shapely.intersects(box_polygons(boxes), box_polygons(ego))


def dense_observation(
    poses: np.ndarray,
    velocity: np.ndarray,
    valid: np.ndarray,
    size: np.ndarray,
    agent_class: np.ndarray,
    red_light_polygons: list[list[shapely.Polygon]] | None = None,
) -> Observation:
    """Boxes at every 10 Hz step: centre poses ``(M, S, 3)``, velocity ``(M, S, 2)``, valid ``(M, S)``, size ``(M, 3)``
    (length, width, height), ``BoxClass`` codes ``(M,)``. ``red_light_polygons[s]`` are step ``s``'s red-light
    pseudo-objects."""
    num_tracks, num_steps = valid.shape
    size = np.asarray(size, np.float64).reshape(num_tracks, 3)
    coords = box_coords(poses[..., :2], poses[..., 2], size[:, None, 0], size[:, None, 1])
    step_of, track_of = np.nonzero(valid.T)  # sorted by step
    track_corners = coords[track_of, step_of]
    track_polygons = box_polygons(track_corners)
    red = red_light_polygons if red_light_polygons is not None else [[] for _ in range(num_steps)]
    if len(red) != num_steps:
        raise ValueError(f"red_light_polygons has {len(red)} steps, the boxes {num_steps}: give one list per step")
    lights = [np.array(step, dtype=object).reshape(-1) for step in red]
    num_red = sum(len(step) for step in lights)
    red_of = np.repeat(np.arange(num_steps), [len(step) for step in lights])
    step_of = np.concatenate([step_of, red_of])
    order = np.argsort(step_of, kind="stable")
    polygons = np.concatenate([track_polygons, *lights])[order] if num_red else track_polygons
    corners = np.concatenate([track_corners[:, :4], np.full((num_red, 4, 2), np.nan)])[order]
    objects = np.concatenate([track_of, num_tracks + np.arange(num_red)])[order]
    step_of = step_of[order]
    first = np.argmax(valid, axis=1)
    first_velocity = velocity[np.arange(num_tracks), first] if num_steps else np.zeros((num_tracks, 2))
    is_agent = np.isin(agent_class, AGENT_CLASSES)
    centroids = shapely.get_coordinates(shapely.centroid(polygons)).reshape(-1, 2)
    step_offsets, step_geoms = _step_layout(step_of, num_steps)
    return Observation(
        polygons=polygons,
        corners=corners,
        axes=Axes.of(corners),
        objects=objects.astype(np.int64),
        centroids=centroids,
        radius=_enclosing_radius(polygons, centroids),
        step_offsets=step_offsets,
        step_geoms=step_geoms,
        object_is_agent=np.concatenate([is_agent, np.zeros(num_red, bool)]),
        object_speed=np.concatenate([np.hypot(first_velocity[:, 0], first_velocity[:, 1]), np.zeros(num_red)]),
        object_is_red_light=np.concatenate([np.zeros(num_tracks, bool), np.ones(num_red, bool)]),
    )
