"""TLC, NAVSIM v2's traffic light compliance: does the ego box touch a red light on its route at any step?

Red lights are the polygons of lanes / lane connectors that are red at a step *and* lie on the log's **uncorrected**
route (``light_route_lane_ids``, ``MetricCacheProcessor._load_route_dicts``), not on PDM-Closed's corrected route
that ONCOMING_TRAFFIC uses: a red connector off that route never counts. The light status comes from the log at
2 Hz and is held for the 5 steps of 0.1 s that follow (``_interpolate_traffic_light_status``), so step k reads the
latest keyframe at or before it; a light that turns red while the ego is on its connector fails TLC. Every one of
the 41 steps counts, step 0 included, and "touch" is shapely ``intersects`` with the whole polygon
(``PDMScorer._calculate_traffic_light_compliance`` over the red-light pseudo-objects of the observation).
"""

from functools import reduce

import numpy as np
import shapely

from lead_s2r.scoring.pdm.footprint import Corner, box_polygons
from lead_s2r.scoring.pdm.map_flags import LANE_KINDS
from lead_s2r.scoring.pdm.scene import PDMScene

#: Tolerance [s] when matching step times with keyframe times.
TIME_SLACK_S = 1e-6


def _lane_polygons(scene: PDMScene, ids: np.ndarray) -> dict[int, shapely.Polygon]:
    """The LANE / LANE_CONNECTOR polygons of ``ids`` (the first when an id repeats; other kinds may share ids)."""
    offsets = np.asarray(scene.polygon_offsets, np.int64)
    out: dict[int, shapely.Polygon] = {}
    is_lane = np.isin(scene.polygon_kind, LANE_KINDS)
    for k in np.flatnonzero(np.isin(scene.polygon_id, ids) & is_lane):
        out.setdefault(int(scene.polygon_id[k]), shapely.Polygon(scene.polygon_xy[offsets[k] : offsets[k + 1]]))
    return out


def red_light_polygons(scene: PDMScene, num_steps: int, interval: float = 0.1) -> list[list[shapely.Polygon]]:
    """Per step ``t = k * interval`` the polygons of the on-route lanes that are red at the latest keyframe at or
    before ``t``. Red ids without a polygon in the scene's map are skipped, as NAVSIM's route dictionary holds only
    lanes of the map."""
    keyframe_t = np.asarray(scene.red_light_t, np.float64)
    offsets = np.asarray(scene.red_light_offsets, np.int64)
    if len(offsets) != len(keyframe_t) + 1:
        raise ValueError(
            f"scene {scene.key!r}: red_light_offsets has {len(offsets)} entries for {len(keyframe_t)} keyframes; "
            "it needs one more than red_light_t (rebuild scoring.npz)"
        )
    on_route = np.asarray(scene.light_route_lane_ids, np.int64)
    polygons = _lane_polygons(scene, np.intersect1d(np.asarray(scene.red_light_ids, np.int64), on_route))
    keyframe = np.searchsorted(keyframe_t, np.arange(num_steps) * interval + TIME_SLACK_S, side="right") - 1
    per_keyframe = [
        [polygons[i] for i in np.unique(scene.red_light_ids[offsets[k] : offsets[k + 1]]) if int(i) in polygons]
        for k in range(len(keyframe_t))
    ]
    return [per_keyframe[k] if k >= 0 else [] for k in keyframe]


def on_red_light(ego_coords: np.ndarray, red_lights: list[list[shapely.Polygon]]) -> np.ndarray:
    """``(N, T)``: the ego box ``(N, T, 5, 2)`` intersects a red-light polygon of its step. Only boxes whose bounding
    box meets a light's are handed to GEOS: a box's bounds are the minimum and maximum of the very corners its polygon
    is built from, so a box whose bounds miss every light's cannot touch one (no arithmetic, nothing to round)."""
    num_rows, num_steps = ego_coords.shape[:2]
    if len(red_lights) != num_steps:
        raise ValueError(f"red lights are given for {len(red_lights)} steps, the ego boxes have {num_steps}")
    touching = np.zeros((num_rows, num_steps), bool)
    for step, lights in enumerate(red_lights):
        if lights:
            shapes = np.array(lights, dtype=object)
            shapely.prepare(shapes)  # once per polygon: the lights are the scene's, shared by its steps and calls
            xmin, ymin, xmax, ymax = shapely.bounds(shapes).T
            # the box's bounds, corner by corner (numpy's reductions over an axis of 4 cost far more)
            corners = [ego_coords[:, step, corner] for corner in range(Corner.CENTER)]
            low, high = reduce(np.minimum, corners), reduce(np.maximum, corners)
            meets = (low[:, :1] <= xmax) & (high[:, :1] >= xmin) & (low[:, 1:] <= ymax) & (high[:, 1:] >= ymin)
            near = np.flatnonzero(meets.any(axis=1))
            boxes = box_polygons(np.take(ego_coords[:, step], near, axis=0))  # np.take: faster than fancy indexing
            touching[near, step] = shapely.intersects(shapes[None], boxes[:, None]).any(-1)
    return touching


def traffic_light_compliance(touching: np.ndarray) -> np.ndarray:
    """TLC ``(N,)``: 0 if the ego touches a red light at any step of ``(N, T)``."""
    return np.where(touching.any(axis=-1), 0.0, 1.0)
