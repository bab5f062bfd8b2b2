"""NC (no at-fault collision) and TTC (time to collision within bound): NAVSIM v1.1's
``PDMScorer._calculate_no_at_fault_collision`` / ``_calculate_ttc`` and ``pdm_scorer_utils.get_collision_type``,
with nuPlan-devkit v1.2's ``is_agent_ahead`` (30 deg), ``is_agent_behind`` (150 deg) and ``is_track_stopped``.

Both walk the steps in order with a per-proposal list of objects to ignore: an overlap that is not the ego's fault
(NC) or not threatening (TTC) puts the object on the list for every later check of that proposal. Here every
overlap is classified at once and the walk becomes "count a violation only if it comes before the first harmless
overlap with the same object". Official behaviours reproduced on purpose:

* NC classifies with the object's *first* appearance (static kind, or its speed then <= 0.05 m/s: STOPPED_TRACK, at
  fault) but with its polygon and centroid at the step of the overlap. Order: ego speed <= 0.05 m/s (STOPPED_EGO, not at
  fault); STOPPED_TRACK; centroid more than 150 deg off the ego heading seen from the rear axle (ACTIVE_REAR, not at
  fault); ego front edge (exterior coords 0 -> 3) touches the object (ACTIVE_FRONT, at fault); else ACTIVE_LATERAL, at
  fault only while the ego is in MULTIPLE_LANES or NON_DRIVABLE_AREA. An at-fault overlap scores 0 with an agent
  (vehicle, pedestrian, bicycle) and 0.5 with a static object. Overlaps at t = 0 count.
* TTC moves the ego box (centre slot replaced by the front-left corner) along its heading at its current speed by
  0, 0.3, 0.6 and 0.9 s (``float(k) * 0.1``) and checks the observation at step t + k. Skipped: red lights, ignored
  objects and an ego slower than 5e-3 m/s. A violation is an object within 30 deg ahead, or one not behind (150 deg)
  while the ego is in MULTIPLE_LANES, NON_DRIVABLE_AREA or has its rear axle inside an INTERSECTION. TTC's ignore
  list is its own (NC's does not carry over).
* NAVSIM queries an STRtree per step with predicate "intersects"; here candidate pairs come from overlapping
  enclosing circles (a superset of the intersecting pairs), red lights are dropped (NC and TTC skip them), and the
  separating-axis test decides, GEOS ``intersects`` where floats cannot (``overlap``), so the pairs are the same
  and polygons are built only for the few pairs that touch within rounding.
* The relative angle is ``arccos`` of the dot product without clipping; a centroid exactly at the rear axle gives
  NaN, which is neither ahead nor behind.
"""

from collections.abc import Callable

import numpy as np
import shapely
from numba import njit

from lead_s2r.scoring.pdm.footprint import Corner, box_polygons, heading_directions
from lead_s2r.scoring.pdm.observation import Observation
from lead_s2r.scoring.pdm.overlap import convex_intersects
from lead_s2r.scoring.pdm.state import StateIndex

STOPPED_EGO_SPEED = 5e-2  # [m/s] get_collision_type
STOPPED_TRACK_SPEED = 5e-2  # [m/s] nuPlan v1.2 is_track_stopped
TTC_STOPPED_SPEED = 5e-3  # [m/s] PDMScorerConfig.stopped_speed_threshold
AHEAD_DEG = 30.0
BEHIND_DEG = 150.0
STATIC_AT_FAULT_SCORE = 0.5
TTC_OFFSETS = (0, 3, 6, 9)  # steps: np.arange(0, int(1.0 / 0.1), 3)
#: Slack [m] on the bounding-circle test that picks candidate pairs, far above any rounding in the box corners.
CIRCLE_SLACK = 1e-6


def candidate_pairs(
    observation: Observation, x: np.ndarray, y: np.ndarray, obs_steps: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(query, geometry)`` pairs whose enclosing circles overlap: query boxes of centre ``(x, y)``, each
    ``(P, N)`` (NaN: no query), and enclosing radius ``radius``, query ``(p, n)`` (flat index ``p * N + n``) against
    the geometries of observation step ``obs_steps[p]``. Every intersecting pair is among them, so the exact test
    runs on few pairs and no STRtree is needed. Ordered by geometry slot, then query."""
    reach = observation.radius + (radius + CIRCLE_SLACK)
    geoms = observation.step_geoms[obs_steps]  # (P, Gmax), -1 pads
    x, y = np.ascontiguousarray(x, np.float64), np.ascontiguousarray(y, np.float64)
    count = _overlapping_circles(geoms, observation.centroids, reach, x, y, None, None)
    queries, geometries = np.empty(count, np.int64), np.empty(count, np.int64)
    _overlapping_circles(geoms, observation.centroids, reach, x, y, queries, geometries)
    return queries, geometries


@njit(cache=True)
def _overlapping_circles(
    geoms: np.ndarray, centroids: np.ndarray, reach: np.ndarray, x: np.ndarray, y: np.ndarray,
    queries: np.ndarray | None, geometries: np.ndarray | None,
) -> int:  # fmt: skip
    """Counts the pairs of :func:`candidate_pairs` or, given arrays of that length, writes them."""
    num_slots, num_rows = x.shape
    found = 0
    for slot in range(geoms.shape[1]):
        for p in range(num_slots):
            geom = geoms[p, slot]
            if geom < 0:
                continue
            centre_x, centre_y, limit = centroids[geom, 0], centroids[geom, 1], reach[geom] * reach[geom]
            for n in range(num_rows):
                dx, dy = centre_x - x[p, n], centre_y - y[p, n]
                if dx * dx + dy * dy <= limit:
                    if queries is not None and geometries is not None:
                        queries[found], geometries[found] = p * num_rows + n, geom
                    found += 1
    return found


def find_hits(
    observation: Observation,
    x: np.ndarray,
    y: np.ndarray,
    obs_steps: np.ndarray,
    boxes: Callable[[np.ndarray], np.ndarray],
    radius: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``(query, geometry)`` pairs that intersect, for query boxes of centre ``(x, y)`` ``(P, N)`` (NaN: no query)
    at observation steps ``obs_steps (P,)``, queries as flat indices ``p * N + n``. ``boxes(queries)`` gives the
    ``(n, 5, 2)`` corners and centre of the queries asked for: only those with a candidate geometry are built, and
    polygons only for the pairs floats cannot decide. The pairs come in no particular order."""
    query, geom = candidate_pairs(observation, x, y, obs_steps, radius)
    usable = ~observation.object_is_red_light[observation.objects[geom]]
    query, geom = query[usable], geom[usable]
    coords = boxes(query)

    def exact(pairs: np.ndarray) -> np.ndarray:
        return shapely.intersects(box_polygons(coords[pairs]), observation.polygons[geom[pairs]])

    corners = np.take(observation.corners, geom, axis=0)
    intersects = convex_intersects(coords[:, : Corner.CENTER], corners, exact, observation.axes[geom])
    return query[intersects], geom[intersects]


def _at(array: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """``array[first, second]`` by ``np.take`` on the first two axes flattened: the same elements, several times
    faster than numpy's fancy indexing with two index arrays (or one over rows of a multi-dimensional array)."""
    return np.take(array.reshape(-1, *array.shape[2:]), first * array.shape[1] + second, axis=0)


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
    _, group = np.unique(row * (int(obj.max()) + 1) + obj, return_inverse=True)
    release = np.full(group.max() + 1, np.inf)
    np.minimum.at(release, group[~violation], order[~violation])
    return violation & (order < release[group])


def _first_step(rows: np.ndarray, steps: np.ndarray, num_rows: int) -> np.ndarray:
    """Per row the smallest step among ``(rows, steps)`` pairs, -1 for rows without any."""
    first = np.full(num_rows, np.iinfo(np.int64).max)
    np.minimum.at(first, rows, steps.astype(np.int64))
    return np.where(first == np.iinfo(np.int64).max, -1, first)


def step_hits(ego_coords: np.ndarray, ego_radius: float, observation: Observation) -> tuple[np.ndarray, np.ndarray]:
    """``(query, geometry)`` pairs where the ego box of (row, step), query ``step * N + row``, intersects a geometry
    of the observation at its own step (red lights left out), for boxes ``(N, T, 5, 2)`` of enclosing radius
    ``ego_radius``: NC's overlaps, and TTC's at offset 0 (the same boxes and steps)."""
    num_rows, num_steps = ego_coords.shape[:2]
    centers = ego_coords[:, :, Corner.CENTER].transpose(2, 1, 0)  # (2, T, N): a step's rows side by side

    def boxes(query: np.ndarray) -> np.ndarray:
        step, row = np.divmod(query, num_rows)
        return _at(ego_coords, row, step)

    return find_hits(observation, *centers, np.arange(num_steps), boxes, ego_radius)


def no_at_fault_collisions(
    states: np.ndarray,
    ego_coords: np.ndarray,
    hits: tuple[np.ndarray, np.ndarray],
    observation: Observation,
    lanes_or_off_road: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NC ``(N,)`` in {0, 0.5, 1}, the first at-fault step ``(N,)`` and the observation object hit there ``(N,)``
    (a track index: the scene's agent row; -1 if none), for states ``(N, T, 11)``, their boxes ``(N, T, 5, 2)`` and
    the boxes' :func:`step_hits`; ``lanes_or_off_road (N, T)`` = MULTIPLE_LANES or NON_DRIVABLE_AREA."""
    num_rows = ego_coords.shape[0]
    query, geom = hits
    step, row = np.divmod(query, num_rows)
    obj = observation.objects[geom]
    ego = _at(states, row, step)
    ego_stopped = np.hypot(ego[:, StateIndex.VELOCITY_X], ego[:, StateIndex.VELOCITY_Y]) <= STOPPED_EGO_SPEED
    track_stopped = ~observation.object_is_agent[obj] | (observation.object_speed[obj] <= STOPPED_TRACK_SPEED)
    centroids = np.take(observation.centroids, geom, axis=0)
    behind = relative_angle(ego[:, : StateIndex.HEADING + 1], centroids) > np.deg2rad(BEHIND_DEG)
    front = np.take(_at(ego_coords, row, step), [Corner.FRONT_LEFT, Corner.FRONT_RIGHT], axis=1)

    def exact(pairs: np.ndarray) -> np.ndarray:
        return shapely.intersects(shapely.linestrings(front[pairs]), observation.polygons[geom[pairs]])

    front_hit = convex_intersects(front, np.take(observation.corners, geom, axis=0), exact, observation.axes[geom])
    lateral = ~ego_stopped & ~track_stopped & ~behind & ~front_hit
    at_fault = ~ego_stopped & (track_stopped | (~behind & front_hit) | (lateral & _at(lanes_or_off_road, row, step)))
    counted = counted_before_release(row, obj, step, at_fault)
    row, step, obj = row[counted], step[counted], obj[counted]

    scores = np.ones(num_rows)
    np.minimum.at(scores, row, np.where(observation.object_is_agent[obj], 0.0, STATIC_AT_FAULT_SCORE))
    first = _first_step(row, step, num_rows)
    at_first = step == first[row]  # the object hit at a row's first step: the lowest index on a tie
    hit = np.full(num_rows, np.iinfo(np.int64).max)
    np.minimum.at(hit, row[at_first], obj[at_first].astype(np.int64))
    return scores, first, np.where(first >= 0, hit, -1)


def time_to_collision(
    states: np.ndarray,
    ego_coords: np.ndarray,
    ego_radius: float,
    observation: Observation,
    lanes_or_off_road: np.ndarray,
    in_intersection: np.ndarray,
    interval: float = 0.1,
    num_steps: int | None = None,
    hits_at_rest: tuple[np.ndarray, np.ndarray] | None = None,
    along: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """TTC ``(N,)`` in {0, 1} and the first violating ego step ``(N,)`` (-1 if none). Ego steps ``0..num_steps-1`` are
    checked (v1.1: all 41, the observation reaching 0.9 s further; v2: ``num_steps = 41 - 9``).
    ``in_intersection (N, T)``: the rear axle lies inside an INTERSECTION polygon. ``hits_at_rest``: the boxes'
    :func:`step_hits`, which are offset 0's (not moved, the same step): found once for NC and TTC. ``along``: the
    states' :func:`~lead_s2r.scoring.pdm.footprint.heading_directions`, which the ego boxes were built with."""
    num_rows, total_steps = states.shape[:2]
    num_steps = total_steps if num_steps is None else num_steps
    # per (step, row), laid out (S, N) so that the queries' grid (K, S, N) has the rows as its long axis
    speed = np.ascontiguousarray(
        np.hypot(states[:, :num_steps, StateIndex.VELOCITY_X], states[:, :num_steps, StateIndex.VELOCITY_Y]).T
    )
    cos, sin = heading_directions(states) if along is None else along
    per_second = np.ascontiguousarray(cos[:, :num_steps].T) * speed, np.ascontiguousarray(sin[:, :num_steps].T) * speed
    center = ego_coords[:, :num_steps, Corner.CENTER].transpose(2, 1, 0)  # (2, S, N)
    # queries (offset k, step, row): the box moved along its heading at its speed by float(k) * interval, as NAVSIM
    # computes it; none (NaN centre) where the ego stands or the observation ends
    lengths = [float(offset) * interval for offset in TTC_OFFSETS]
    obs_steps = np.arange(num_steps) + np.asarray(TTC_OFFSETS)[:, None]  # (K, S)
    resting = (speed < TTC_STOPPED_SPEED) | (obs_steps[..., None] >= observation.num_steps)  # (K, S, N)
    x, y = (
        np.stack([axis + along * length for length in lengths]) for axis, along in zip(center, per_second, strict=True)
    )
    x[resting] = np.nan
    y[resting] = np.nan

    def boxes(query: np.ndarray) -> np.ndarray:
        offset, step, row = np.unravel_index(query, x.shape)
        shift = np.stack([_at(along, step, row) for along in per_second], -1) * np.array(lengths)[offset, None]
        return _at(ego_coords, row, step) + shift[:, None]

    valid_steps = np.minimum(obs_steps, observation.num_steps - 1).reshape(-1)  # the NaN centres' steps are never read
    first = 0 if hits_at_rest is None else 1  # offset 0's queries come from hits_at_rest where it is given
    skipped = first * num_steps * num_rows
    query, geom = find_hits(
        observation,
        x[first:].reshape(-1, num_rows),
        y[first:].reshape(-1, num_rows),
        valid_steps[first * num_steps :],
        lambda moved: boxes(moved + skipped),
        ego_radius,
    )
    query += skipped
    if first:
        at_rest, at_rest_geom = hits_at_rest
        keep = at_rest < skipped  # the steps TTC checks
        keep[keep] = ~np.isnan(np.take(x.reshape(-1), at_rest[keep]))  # not standing (nor past the observation)
        query, geom = np.concatenate([at_rest[keep], query]), np.concatenate([at_rest_geom[keep], geom])
    offset, step, row = np.unravel_index(query, x.shape)
    order = step * len(TTC_OFFSETS) + offset  # the official walk: steps in order, offsets in order within a step
    rear_axle = _at(states, row, step)[:, : StateIndex.HEADING + 1]
    angle = relative_angle(rear_axle, np.take(observation.centroids, geom, axis=0))
    risky_area = _at(lanes_or_off_road, row, step) | _at(in_intersection, row, step)
    violation = (angle < np.deg2rad(AHEAD_DEG)) | (risky_area & ~(angle > np.deg2rad(BEHIND_DEG)))
    counted = counted_before_release(row, observation.objects[geom], order, violation)
    first = _first_step(row[counted], step[counted], num_rows)
    return np.where(first >= 0, 0.0, 1.0), first
