"""DAC, DDC, EP, LK and the v1.1 aggregation of NAVSIM's ``PDMScorer``: small functions over ``(N, T)`` arrays.

Constants and official behaviours reproduced on purpose:

* DDC: per-step progress ``||centre_t - centre_{t-1}||`` counted only where ONCOMING_TRAFFIC holds, summed over the
  window ``[t - 10, t]`` (horizon 1.0 s / 0.1 s, 11 samples, shorter at the start), maximum over t: 1 below 2 m,
  0.5 below 6 m, else 0. v1.1 has no intersection exclusion (``exclude`` is v2's INTERSECTION mask) and gives DDC
  weight 0: it is reported and never changes the PDMS. Window sums are taken slice by slice as NAVSIM does, so
  floating-point rounding (and hence the band edges) match.
* EP: raw progress = projection of the last box centre onto the centreline minus that of the first, clipped at 0. v1.1
  masks it with NC * DAC and divides by the largest masked progress of the normalisation group when that exceeds 5 m;
  otherwise EP is 1, or 0 where NC * DAC is 0. So EP is 0 whenever NC or DAC is 0. v2 (``ego_progress_v2``) masks only
  the normaliser: ``max`` over the group of raw * NC * DAC * DDC * TLC; above 5 m EP = clip(raw / normaliser, 0, 1) with
  the *unmasked* raw progress, otherwise 1 for every row. So an agent with NC = 0 can have EP = 1.
* LK (v2): the distance from the box centre to the whole centreline linestring, > 0.5 m for ceil(2.0 / 0.1) = 20
  consecutive steps fails. Steps with the centre inside an INTERSECTION are skipped and do not reset the count.
  Every "> 0.5 m" is GEOS's answer (``beyond_lane_limit``).
* PDMS = NC * DAC * (5 * EP + 5 * TTC + 2 * C + 0 * DDC) / 12, in NAVSIM's order of operations.
"""

import numpy as np
import shapely

from lead_s2r.scoring.pdm.map_flags import GRID_CELL_M, BoundsGrid

DDC_HORIZON_S = 1.0
DDC_COMPLIANT_M = 2.0
DDC_VIOLATION_M = 6.0
PROGRESS_THRESHOLD_M = 5.0
LANE_KEEPING_LIMIT_M = 0.5
LANE_KEEPING_WINDOW_S = 2.0
#: [m] a centre whose numpy distance lies this close to the LK limit is measured again by GEOS: far above the
#: rounding of either computation (~1e-9 m at UTM coordinates), so numpy decides only the certain answers
LANE_KEEPING_MARGIN_M = 1e-6
#: [m] a segment's bounding box is grown by the limit plus this before it is gridded: every segment within the limit
#: (and the margin) of a centre is a candidate of the centre's cell, whatever the rounding of the box
LANE_KEEPING_SLACK_M = 0.01
#: v1.1 ``PDMScorerConfig`` weights in ``WeightedMetricIndex`` order: progress, TTC, comfort, driving direction.
V11_WEIGHTS = np.array([5.0, 5.0, 2.0, 0.0])


def drivable_area_compliance(non_drivable_area: np.ndarray) -> np.ndarray:
    """DAC ``(N,)``: 0 if NON_DRIVABLE_AREA holds at any step of ``(N, T)``."""
    return np.where(non_drivable_area.any(axis=-1), 0.0, 1.0)


def first_step(flags: np.ndarray) -> np.ndarray:
    """The first step ``(N,)`` where ``flags (N, T)`` holds, -1 where it never does: where a sub-score failed, for a
    report to name (e.g. the step DAC's NON_DRIVABLE_AREA starts)."""
    return np.where(flags.any(axis=-1), flags.argmax(axis=-1), -1)


def driving_direction_compliance(
    centers: np.ndarray, oncoming: np.ndarray, interval: float = 0.1, exclude: np.ndarray | None = None
) -> np.ndarray:
    """DDC ``(N,)`` in {0, 0.5, 1} from box centres ``(N, T, 2)`` and ONCOMING_TRAFFIC ``(N, T)``; steps in
    ``exclude (N, T)`` (v2: centre inside an INTERSECTION) do not count."""
    progress = np.zeros(oncoming.shape)
    # np.linalg.norm's own sum, x and y apart (numpy's loops over an axis of 2 cost far more)
    dx, dy = (np.diff(centers[..., axis], axis=1) for axis in range(2))
    progress[:, 1:] = np.sqrt(dx * dx + dy * dy)
    counted = oncoming if exclude is None else oncoming & ~exclude
    progress[~counted] = 0.0
    horizon = int(DDC_HORIZON_S / interval)
    windows = np.stack([progress[:, max(0, t - horizon) : t + 1].sum(axis=-1) for t in range(progress.shape[-1])], -1)
    worst = windows.max(axis=-1)
    return np.where(worst < DDC_COMPLIANT_M, 1.0, np.where(worst < DDC_VIOLATION_M, 0.5, 0.0))


def progress_along(centerline: shapely.LineString, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Raw progress ``(N,)`` [m] from centres ``start``/``end`` ``(N, 2)`` projected onto the centreline, >= 0.
    Rows that all start at one point (every simulated row starts at the logged ego) project it once."""
    if len(start) and (start == start[0]).all():
        start = start[:1]
    along = shapely.line_locate_point(centerline, shapely.points(np.concatenate([start, end])))
    return np.clip(along[len(start) :] - along[: len(start)], 0.0, None)


def ego_progress(raw: np.ndarray, multiplier: np.ndarray, reference: int | None) -> tuple[np.ndarray, np.ndarray]:
    """v1.1 EP ``(N,)`` and each row's normaliser [m] from raw progress and NC * DAC ``(N,)``. ``reference=None``:
    all rows form one group (the scorer's own call, as PDM-Closed scores its proposals). ``reference=i``: each row is
    normalised over ``[row i, itself]``, as one ``pdm_score`` call per row with row i as PDM-Closed would be."""
    masked = raw * multiplier
    normaliser = np.full(len(raw), np.max(masked)) if reference is None else np.maximum(masked[reference], masked)
    above = normaliser > PROGRESS_THRESHOLD_M
    with np.errstate(invalid="ignore", divide="ignore"):
        ep = np.where(above, masked / np.where(above, normaliser, 1.0), np.where(multiplier == 0.0, 0.0, 1.0))
    return ep, normaliser


def ego_progress_v2(raw: np.ndarray, multiplier: np.ndarray, reference: int | None) -> tuple[np.ndarray, np.ndarray]:
    """v2 EP ``(N,)`` and each row's normaliser [m]: the same groups as :func:`ego_progress`, the product of the
    multipliers masking only the normaliser."""
    masked = raw * multiplier
    normaliser = np.full(len(raw), np.max(masked)) if reference is None else np.maximum(masked[reference], masked)
    above = normaliser > PROGRESS_THRESHOLD_M
    ep = np.ones(len(raw))
    ep[above] = np.clip(raw[above] / normaliser[above], 0.0, 1.0)
    return ep, normaliser


def lane_keeping(
    centers: np.ndarray, centerline: shapely.LineString, in_intersection: np.ndarray, interval: float = 0.1
) -> tuple[np.ndarray, np.ndarray]:
    """LK ``(N,)`` in {0, 1} and the step it fails at ``(N,)`` (-1 if it does not) from box centres ``(N, T, 2)``;
    ``in_intersection (N, T)`` marks the steps that are skipped."""
    exceeds = beyond_lane_limit(centers, centerline)
    required = int(np.ceil(LANE_KEEPING_WINDOW_S / interval))
    count = np.zeros(len(centers), np.int64)
    failed_at = np.full(len(centers), -1)
    # step by step over contiguous rows; a skipped step keeps the count
    for step, (exceeding, skipped) in enumerate(zip(exceeds.T.copy(), in_intersection.T.copy(), strict=True)):
        count = np.where(skipped, count, np.where(exceeding, count + 1, 0))
        failed_at[(failed_at < 0) & (count >= required)] = step
    return np.where(failed_at >= 0, 0.0, 1.0), failed_at


def beyond_lane_limit(centers: np.ndarray, centerline: shapely.LineString) -> np.ndarray:
    """``shapely.distance(centre, centerline) > LANE_KEEPING_LIMIT_M`` for centres ``(..., 2)``, GEOS's answer
    without a point geometry per centre: a grid over the segments' grown bounding boxes gives each centre the segments
    that can lie within the limit (none: farther), numpy's point-to-segment distance to those decides centres clear of
    the limit by :data:`LANE_KEEPING_MARGIN_M`, and GEOS measures the rest."""
    points = centers.reshape(-1, 2)
    vertices = shapely.get_coordinates(centerline)
    start, end = vertices[:-1], vertices[1:]
    reach = LANE_KEEPING_LIMIT_M + LANE_KEEPING_SLACK_M
    grid = BoundsGrid.build(np.hstack([np.minimum(start, end) - reach, np.maximum(start, end) + reach]), GRID_CELL_M)
    point, entry = grid.candidates(points[:, 0], points[:, 1])  # grouped by point, in increasing order
    segment = grid.members[entry]
    nearest = np.full(len(points), np.inf)
    if len(point):
        first = np.flatnonzero(np.diff(point, prepend=-1))
        x, y = (np.take(points[:, axis], point) for axis in range(2))
        distance = _segment_distance(x, y, np.take(start, segment, axis=0), np.take(end, segment, axis=0))
        nearest[point[first]] = np.minimum.reduceat(distance, first)
    beyond = nearest > LANE_KEEPING_LIMIT_M
    unsure = np.flatnonzero(np.abs(nearest - LANE_KEEPING_LIMIT_M) <= LANE_KEEPING_MARGIN_M)
    beyond[unsure] = shapely.distance(shapely.points(points[unsure]), centerline) > LANE_KEEPING_LIMIT_M
    return beyond.reshape(centers.shape[:-1])


def _segment_distance(x: np.ndarray, y: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """Distance ``(B,)`` from each point ``(x, y)`` to the segment from ``start`` to ``end`` ``(B, 2)`` (a point if
    they meet), x and y apart (numpy's loops over an axis of 2 cost far more)."""
    along_x, along_y = end[:, 0] - start[:, 0], end[:, 1] - start[:, 1]
    offset_x, offset_y = x - start[:, 0], y - start[:, 1]
    squared = along_x * along_x + along_y * along_y
    fraction = np.divide(
        offset_x * along_x + offset_y * along_y, squared, out=np.zeros(len(x)), where=squared > 0.0
    ).clip(0.0, 1.0)
    gap_x, gap_y = offset_x - fraction * along_x, offset_y - fraction * along_y
    return np.sqrt(gap_x * gap_x + gap_y * gap_y)


def pdms_v11(
    nc: np.ndarray, dac: np.ndarray, ep: np.ndarray, ttc: np.ndarray, c: np.ndarray, ddc: np.ndarray
) -> np.ndarray:
    """``PDMScorer._aggregate_scores`` with v1.1 weights."""
    weighted = (np.stack([ep, ttc, c, ddc]) * V11_WEIGHTS[:, None]).sum(axis=0) / V11_WEIGHTS.sum()
    return np.stack([nc, dac]).prod(axis=0) * weighted
