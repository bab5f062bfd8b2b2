"""NC (no at-fault collision) and TTC (time to collision within bound): NAVSIM v1.1's
``PDMScorer._calculate_no_at_fault_collision`` / ``_calculate_ttc`` and ``pdm_scorer_utils.get_collision_type``,
with nuPlan-devkit v1.2's ``is_agent_ahead`` (30 deg), ``is_agent_behind`` (150 deg) and ``is_track_stopped``.

Both walk the steps in order with a per-proposal list of objects to ignore: an overlap that is not the ego's fault
(NC) or not threatening (TTC) puts the object on the list for every later check of that proposal. Here every
overlap is classified at once and the walk becomes "count a violation only if it comes before the first harmless
overlap with the same object". Official behaviours reproduced on purpose:

* NC classifies with the object's *first* appearance (static kind, or its speed then <= 0.05 m/s: STOPPED_TRACK,
  at fault) but with its polygon and centroid at the step of the overlap. Order: ego speed <= 0.05 m/s (STOPPED_EGO,
  not at fault); STOPPED_TRACK; centroid more than 150 deg off the ego heading seen from the rear axle (ACTIVE_REAR,
  not at fault); ego front edge (exterior coords 0 -> 3) touches the object (ACTIVE_FRONT, at fault); else
  ACTIVE_LATERAL, at fault only while the ego is in MULTIPLE_LANES or NON_DRIVABLE_AREA.
  An at-fault overlap scores 0 with an agent (vehicle, pedestrian, bicycle) and 0.5 with a static object. Overlaps
  at t = 0 count.
* TTC moves the ego box (centre slot replaced by the front-left corner) along its heading at its current speed by
  0, 0.3, 0.6 and 0.9 s (``float(k) * 0.1``) and checks the observation at step t + k. Skipped: red lights, ignored
  objects and an ego slower than 5e-3 m/s. A violation is an object within 30 deg ahead, or one not behind (150 deg)
  while the ego is in MULTIPLE_LANES, NON_DRIVABLE_AREA or has its rear axle inside an INTERSECTION. TTC's ignore
  list is its own (NC's does not carry over).
* The relative angle is ``arccos`` of the dot product without clipping; a centroid exactly at the rear axle gives
  NaN, which is neither ahead nor behind.
"""

from dataclasses import dataclass

import numpy as np
import shapely

from lead_s2r.scoring.pdm.footprint import Corner, box_polygons
from lead_s2r.scoring.pdm.observation import Observation
from lead_s2r.scoring.pdm.state import StateIndex

STOPPED_EGO_SPEED = 5e-2  # [m/s] get_collision_type
STOPPED_TRACK_SPEED = 5e-2  # [m/s] nuPlan v1.2 is_track_stopped
TTC_STOPPED_SPEED = 5e-3  # [m/s] PDMScorerConfig.stopped_speed_threshold
AHEAD_DEG = 30.0
BEHIND_DEG = 150.0
STATIC_AT_FAULT_SCORE = 0.5
TTC_OFFSETS = (0, 3, 6, 9)  # steps: np.arange(0, int(1.0 / 0.1), 3)


@dataclass
class Hits:
    """Overlaps found over a run of steps: proposal row, ego step, observation step, object, and the object's
    polygon and centroid at the observation step."""

    row: np.ndarray
    step: np.ndarray
    obs_step: np.ndarray
    obj: np.ndarray
    polygon: np.ndarray
    centroid: np.ndarray

    @classmethod
    def collect(cls, observation: Observation, queries: list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]) -> "Hits":
        """Run each query ``(obs_step, polygons, rows, steps)`` against the tree of ``obs_step``."""
        parts = []
        for obs_step, polygons, rows, steps in queries:
            query, geom = observation.query(obs_step, polygons)
            obj = observation.objects[obs_step][geom]
            parts.append(
                (
                    rows[query],
                    steps[query],
                    np.full(len(query), obs_step),
                    obj,
                    observation.polygons[obs_step][geom],
                    observation.centroids[obs_step][geom],
                )
            )
        if not parts:
            empty = np.zeros(0, np.int64)
            return cls(empty, empty, empty, empty, np.zeros(0, object), np.zeros((0, 2)))
        return cls(*(np.concatenate(column) for column in zip(*parts, strict=True)))

    def select(self, keep: np.ndarray) -> "Hits":
        return Hits(
            self.row[keep],
            self.step[keep],
            self.obs_step[keep],
            self.obj[keep],
            self.polygon[keep],
            self.centroid[keep],
        )


def relative_angle(poses: np.ndarray, points: np.ndarray) -> np.ndarray:
    """nuPlan ``get_agent_relative_angle``: angle between the heading of ``poses (..., 3)`` and the direction to
    ``points (..., 2)``."""
    dx, dy = points[..., 0] - poses[..., 0], points[..., 1] - poses[..., 1]
    norm = np.sqrt(dx * dx + dy * dy)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.arccos(np.cos(poses[..., 2]) * (dx / norm) + np.sin(poses[..., 2]) * (dy / norm))


def counted_before_release(row: np.ndarray, obj: np.ndarray, order: np.ndarray, violation: np.ndarray) -> np.ndarray:
    """Which violations count under the official walk: those ordered before the first non-violation of the same
    (row, object), after which the object is ignored for that row."""
    if len(row) == 0:
        return np.zeros(0, bool)
    _, group = np.unique(np.stack([row, obj]), axis=1, return_inverse=True)
    group = group.reshape(-1)
    release = np.full(group.max() + 1, np.inf)
    np.minimum.at(release, group[~violation], order[~violation])
    return violation & (order < release[group])


def _first_step(rows: np.ndarray, steps: np.ndarray, num_rows: int) -> np.ndarray:
    """Per row the smallest step among ``(rows, steps)`` pairs, -1 for rows without any."""
    first = np.full(num_rows, np.iinfo(np.int64).max)
    np.minimum.at(first, rows, steps.astype(np.int64))
    return np.where(first == np.iinfo(np.int64).max, -1, first)


def _usable(hits: Hits, observation: Observation) -> np.ndarray:
    return ~observation.object_is_red_light[hits.obj] & ~observation.initially_ignored[hits.obj]


def no_at_fault_collisions(
    states: np.ndarray,
    ego_polygons: np.ndarray,
    ego_coords: np.ndarray,
    observation: Observation,
    lanes_or_off_road: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """NC ``(N,)`` in {0, 0.5, 1} and the first at-fault step ``(N,)`` (-1 if none), for states ``(N, T, 11)``,
    their polygons ``(N, T)`` and boxes ``(N, T, 5, 2)``; ``lanes_or_off_road (N, T)`` = MULTIPLE_LANES or
    NON_DRIVABLE_AREA."""
    num_rows, num_steps = ego_polygons.shape
    rows = np.arange(num_rows)
    hits = Hits.collect(observation, [(t, ego_polygons[:, t], rows, np.full(num_rows, t)) for t in range(num_steps)])
    hits = hits.select(_usable(hits, observation))
    ego = states[hits.row, hits.step]
    ego_speed = np.hypot(ego[:, StateIndex.VELOCITY_X], ego[:, StateIndex.VELOCITY_Y])
    ego_stopped = ego_speed <= STOPPED_EGO_SPEED
    track_stopped = ~observation.object_is_agent[hits.obj] | (observation.object_speed[hits.obj] <= STOPPED_TRACK_SPEED)
    behind = relative_angle(ego[:, : StateIndex.HEADING + 1], hits.centroid) > np.deg2rad(BEHIND_DEG)
    front = ego_coords[hits.row, hits.step][:, [Corner.FRONT_LEFT, Corner.FRONT_RIGHT]]
    front_hit = shapely.intersects(shapely.linestrings(front), hits.polygon)
    lateral = ~ego_stopped & ~track_stopped & ~behind & ~front_hit
    at_fault = ~ego_stopped & (
        track_stopped | (~behind & front_hit) | (lateral & lanes_or_off_road[hits.row, hits.step])
    )
    counted = counted_before_release(hits.row, hits.obj, hits.step, at_fault)

    severity = np.where(observation.object_is_agent[hits.obj], 0.0, STATIC_AT_FAULT_SCORE)
    scores = np.ones(num_rows)
    np.minimum.at(scores, hits.row[counted], severity[counted])
    return scores, _first_step(hits.row[counted], hits.step[counted], num_rows)


def ttc_polygons(states: np.ndarray, ego_coords: np.ndarray, interval: float, offsets: tuple[int, ...]) -> np.ndarray:
    """Ego boxes ``(N, T, len(offsets))`` moved ahead at constant speed along the heading by ``offset * interval``."""
    speed = np.hypot(states[..., StateIndex.VELOCITY_X], states[..., StateIndex.VELOCITY_Y])
    heading = states[..., StateIndex.HEADING]
    per_second = np.stack([np.cos(heading) * speed, np.sin(heading) * speed], axis=-1)
    ring = ego_coords.copy()
    ring[:, :, Corner.CENTER] = ring[:, :, Corner.FRONT_LEFT]
    moved = np.stack([ring + per_second[:, :, None] * (float(k) * interval) for k in offsets], axis=2)
    return box_polygons(moved)


def time_to_collision(
    states: np.ndarray,
    ego_coords: np.ndarray,
    observation: Observation,
    lanes_or_off_road: np.ndarray,
    in_intersection: np.ndarray,
    interval: float = 0.1,
    offsets: tuple[int, ...] = TTC_OFFSETS,
    num_steps: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """TTC ``(N,)`` in {0, 1} and the first violating ego step ``(N,)`` (-1 if none). Ego steps ``0..num_steps-1`` are
    checked (v1.1: all 41, the observation reaching 0.9 s further; v2: ``num_steps = 41 - 9``).
    ``in_intersection (N, T)``: the rear axle lies inside an INTERSECTION polygon."""
    num_rows, total_steps = states.shape[:2]
    num_steps = total_steps if num_steps is None else num_steps
    polygons = ttc_polygons(states, ego_coords, interval, offsets)
    speed = np.hypot(states[..., StateIndex.VELOCITY_X], states[..., StateIndex.VELOCITY_Y])
    rows = np.arange(num_rows)
    queries = []
    for obs_step in range(min(num_steps - 1 + max(offsets), observation.num_steps - 1) + 1):
        pairs = [(t, k) for k, offset in enumerate(offsets) if 0 <= (t := obs_step - offset) < num_steps]
        if pairs:
            steps = np.repeat([t for t, _ in pairs], num_rows)
            ks = np.repeat([k for _, k in pairs], num_rows)
            query_rows = np.tile(rows, len(pairs))
            queries.append((obs_step, polygons[query_rows, steps, ks], query_rows, steps * len(offsets) + ks))
    hits = Hits.collect(observation, queries)
    step = hits.step // len(offsets)
    keep = _usable(hits, observation) & (speed[hits.row, step] >= TTC_STOPPED_SPEED)
    hits, step, order = hits.select(keep), step[keep], hits.step[keep]
    rear_axle = states[hits.row, step, : StateIndex.HEADING + 1]
    angle = relative_angle(rear_axle, hits.centroid)
    risky_area = lanes_or_off_road[hits.row, step] | in_intersection[hits.row, step]
    violation = (angle < np.deg2rad(AHEAD_DEG)) | (risky_area & ~(angle > np.deg2rad(BEHIND_DEG)))
    counted = counted_before_release(hits.row, hits.obj, order, violation)
    first = _first_step(hits.row[counted], step[counted], num_rows)
    return np.where(first >= 0, 0.0, 1.0), first
