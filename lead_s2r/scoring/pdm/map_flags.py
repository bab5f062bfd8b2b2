"""Where the ego is on the map, per proposal and step: NAVSIM's ``PDMScorer._calculate_ego_area`` and
``PDMDrivableMap.is_in_layer``, with one STRtree "within" query for all points instead of a loop over polygons.

The map is what ``PDMDrivableMap.from_simulation`` holds: ROADBLOCK, LANE, LANE_CONNECTOR, INTERSECTION and
CARPARK_AREA polygons. ROADBLOCK_CONNECTOR and WALKWAY polygons of the scene are left out, as NAVSIM leaves them out
(a roadblock connector counts only through its lane connectors; nuPlan's DRIVABLE_AREA layer is never queried).
"Inside" is strict (``shapely.vectorized.contains``): a point on a polygon's edge is outside it.

* NON_DRIVABLE_AREA: some corner (of 4; the centre is not checked) lies in no ROADBLOCK, INTERSECTION or CARPARK_AREA.
  Lanes do not count as drivable.
* MULTIPLE_LANES: more than one LANE/LANE_CONNECTOR polygon holds a corner, and none holds all four.
* ONCOMING_TRAFFIC: the box centre lies in no LANE/LANE_CONNECTOR whose id is on the route (``route_lane_ids``).
* INTERSECTION membership (TTC, and v2's DDC/LK exclusions) is tested on whatever point the caller gives.
"""

from dataclasses import dataclass

import numpy as np
import shapely
from shapely import STRtree

from lead_s2r.schema import MapKind
from lead_s2r.scoring.pdm.footprint import Corner
from lead_s2r.scoring.pdm.scene import PDMScene

SCORED_KINDS = (MapKind.ROADBLOCK, MapKind.LANE, MapKind.LANE_CONNECTOR, MapKind.INTERSECTION, MapKind.CARPARK_AREA)
DRIVABLE_KINDS = (MapKind.ROADBLOCK, MapKind.INTERSECTION, MapKind.CARPARK_AREA)
LANE_KINDS = (MapKind.LANE, MapKind.LANE_CONNECTOR)
NUM_CORNERS = 4


@dataclass
class DrivableMap:
    """The scene's scored polygons (kinds in :data:`SCORED_KINDS`) with their ids, kinds and an STRtree."""

    polygons: np.ndarray  # (K,) shapely Polygons
    ids: np.ndarray  # (K,) int64
    kinds: np.ndarray  # (K,) MapKind codes
    tree: STRtree

    @classmethod
    def from_scene(cls, scene: PDMScene) -> "DrivableMap":
        offsets = np.asarray(scene.polygon_offsets, np.int64)
        ring_of_point = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
        rings = shapely.linearrings(np.asarray(scene.polygon_xy, np.float64), indices=ring_of_point)
        keep = np.isin(scene.polygon_kind, SCORED_KINDS)
        if len(rings) != len(keep):
            raise ValueError(
                f"scene {scene.key!r}: polygon_offsets describe {len(rings)} polygons with points, polygon_kind has "
                f"{len(keep)}; every polygon needs at least one point (rebuild scoring.npz)"
            )
        polygons = shapely.polygons(rings[keep])
        return cls(
            polygons,
            np.asarray(scene.polygon_id, np.int64)[keep],
            np.asarray(scene.polygon_kind)[keep],
            STRtree(polygons),
        )

    def points_within(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(point index, polygon index)`` of every point ``(P, 2)`` strictly inside a polygon."""
        hits = self.tree.query(shapely.points(points), predicate="within")
        return hits[0], hits[1]

    def in_kind(self, points: np.ndarray, kinds: tuple[MapKind, ...]) -> np.ndarray:
        """``(...)`` whether each point ``(..., 2)`` lies strictly inside a polygon of one of ``kinds``."""
        flat = points.reshape(-1, 2)
        point, polygon = self.points_within(flat)
        inside = np.zeros(len(flat), bool)
        inside[point[np.isin(self.kinds[polygon], kinds)]] = True
        return inside.reshape(points.shape[:-1])


@dataclass
class EgoAreas:
    """``(N, T)`` flags of NAVSIM's ``EgoAreaIndex``."""

    multiple_lanes: np.ndarray
    non_drivable_area: np.ndarray
    oncoming_traffic: np.ndarray


def ego_areas(drivable_map: DrivableMap, coords: np.ndarray, route_lane_ids: np.ndarray) -> EgoAreas:
    """The three ego-area flags of boxes ``(N, T, 5, 2)`` (4 corners + centre)."""
    n_rows, n_steps, n_points, _ = coords.shape
    point, polygon = drivable_map.points_within(coords.reshape(-1, 2))
    box, corner = np.divmod(point, n_points)
    kind = drivable_map.kinds[polygon]
    is_corner = corner != Corner.CENTER
    num_boxes = n_rows * n_steps

    drivable_corners = np.zeros((num_boxes, n_points), bool)
    drivable = np.isin(kind, DRIVABLE_KINDS) & is_corner
    drivable_corners[box[drivable], corner[drivable]] = True
    non_drivable = drivable_corners[:, :NUM_CORNERS].sum(-1) < NUM_CORNERS

    lane = np.isin(kind, LANE_KINDS)
    pairs, corners_in_lane = np.unique(
        box[lane & is_corner] * len(drivable_map.ids) + polygon[lane & is_corner], return_counts=True
    )
    lane_box = pairs // len(drivable_map.ids) if len(drivable_map.ids) else pairs
    lanes_touched = np.bincount(lane_box, minlength=num_boxes)
    all_corners_in_one = np.bincount(lane_box, weights=corners_in_lane == NUM_CORNERS, minlength=num_boxes) > 0
    multiple_lanes = (lanes_touched > 1) & ~all_corners_in_one

    on_route = lane & ~is_corner & np.isin(drivable_map.ids[polygon], route_lane_ids)
    oncoming = np.ones(num_boxes, bool)
    oncoming[box[on_route]] = False

    shape = (n_rows, n_steps)
    return EgoAreas(multiple_lanes.reshape(shape), non_drivable.reshape(shape), oncoming.reshape(shape))
