"""A small nuPlan-style road network written as a GeoPackage (``maps/<location>/<version>/map.gpkg``).

The network, in local metres before :data:`ORIGIN` is added (nuPlan maps are in UTM, so coordinates are large):

* roadblock 101: eastbound, x 0..100, lanes 1011 (y = -1.75, the right lane) and 1012 (y = +1.75);
* intersection 301: x 100..115, y -3.5..14, crossed by lane connectors 2011 (1011 -> 1021, straight),
  2012 (1012 -> 1022, straight) and 2021 (1012 -> 1032, a left turn of radius 12.25 m under a traffic light);
* roadblock 102: eastbound, x 115..200, lanes 1021, 1022; roadblock 103: northbound, x 107..114, y 14..100,
  lanes 1031 (x = 108.75) and 1032 (x = 112.25); roadblock connectors 201 (101 -> 102) and 202 (101 -> 103);
* car park 401 south of roadblock 101 and walkway 501 along its southern edge.

The intersection is 15 m across, as a junction of two-lane roads is, and reaches 1 m east of the northbound road:
the front corner of a car whose rear axle follows a turn's centreline sweeps outside the lane (more so as NAVSIM's
tracker lags the logged heading), and on a tighter arc its yaw rate leaves NAVSIM's comfort bounds at any usable
speed, so a logged human could not keep the PDM score's rules.

Geometry is written with pyogrio (GDAL's GPKG driver) so the file is a real GeoPackage any GIS tool opens.
"""

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyogrio
import shapely

ORIGIN = np.array([664_000.0, 3_996_000.0])
LOCATION = "us-nv-las-vegas-strip"
MAP_VERSION = "9.15.1915"
CRS = "EPSG:32611"
HALF_LANE = 1.75
#: Where the junction starts (end of roadblock 101), where roadblock 102 starts and where roadblock 103 starts.
JUNCTION_X, EAST_X, NORTH_Y = 100.0, 115.0, 14.0
#: The west and east edges of roadblock 103.
NORTH_ROAD_X = (107.0, 114.0)
#: The left turn's centreline: from lane 1012 (y = 1.75) to lane 1032 (1.75 m inside 103's east edge), a quarter
#: circle.
TURN_RADIUS = NORTH_Y - HALF_LANE
TURN_CENTRE = (JUNCTION_X, NORTH_Y)


@dataclass(frozen=True)
class Lane:
    """A lane or lane connector: its id, parent (roadblock or roadblock connector) and local centerline."""

    fid: int
    parent: int
    centerline: tuple[tuple[float, float], ...]
    speed_limit: float
    index: int = 0
    from_lane: int | None = None
    to_lane: int | None = None


def _arc(n: int = 32) -> tuple[tuple[float, float], ...]:
    """Left turn from (100, 1.75) heading east to (112.25, 14) heading north, around :data:`TURN_CENTRE`."""
    angles = np.linspace(-math.pi / 2, 0.0, n)
    cx, cy = TURN_CENTRE
    return tuple((cx + TURN_RADIUS * math.cos(a), cy + TURN_RADIUS * math.sin(a)) for a in angles)


WEST_LANE, EAST_LANE = NORTH_ROAD_X[0] + HALF_LANE, NORTH_ROAD_X[1] - HALF_LANE
LANES = (
    Lane(1011, 101, ((0.0, -1.75), (JUNCTION_X, -1.75)), 13.4, index=0),
    Lane(1012, 101, ((0.0, 1.75), (JUNCTION_X, 1.75)), 13.4, index=1),
    Lane(1021, 102, ((EAST_X, -1.75), (200.0, -1.75)), 13.4, index=0),
    Lane(1022, 102, ((EAST_X, 1.75), (200.0, 1.75)), 13.4, index=1),
    Lane(1031, 103, ((WEST_LANE, NORTH_Y), (WEST_LANE, 100.0)), 11.2, index=1),
    Lane(1032, 103, ((EAST_LANE, NORTH_Y), (EAST_LANE, 100.0)), 11.2, index=0),
)
LANE_CONNECTORS = (
    Lane(2011, 201, ((JUNCTION_X, -1.75), (EAST_X, -1.75)), 13.4, from_lane=1011, to_lane=1021),
    Lane(2012, 201, ((JUNCTION_X, 1.75), (EAST_X, 1.75)), 13.4, from_lane=1012, to_lane=1022),
    Lane(2021, 202, _arc(), 8.0, from_lane=1012, to_lane=1032),
)
ROADBLOCKS = {
    101: (0.0, -3.5, JUNCTION_X, 3.5),
    102: (EAST_X, -3.5, 200.0, 3.5),
    103: (NORTH_ROAD_X[0], NORTH_Y, NORTH_ROAD_X[1], 100.0),
}
ROADBLOCK_CONNECTORS = {201: (101, 102), 202: (101, 103)}
INTERSECTIONS = {301: (JUNCTION_X, -3.5, EAST_X, NORTH_Y)}
CARPARKS = {401: (20.0, -25.0, 60.0, -5.5)}
WALKWAYS = {501: (0.0, -5.5, 200.0, -3.5)}
#: Lane connectors controlled by a traffic light.
TRAFFIC_LIGHT_CONNECTORS = (2012, 2021)


def lane_polygon(lane: Lane) -> shapely.Polygon:
    """The lane's area: its centerline widened to one lane width with flat ends."""
    return shapely.LineString(lane.centerline).buffer(HALF_LANE, cap_style="flat")


def _boxes(table: dict[int, tuple[float, float, float, float]]) -> tuple[list[int], list[shapely.Geometry]]:
    return list(table), [shapely.box(*bounds) for bounds in table.values()]


def _write(path: Path, layer: str, fids: list[int], geometries: list, geometry_type: str, **columns: list) -> None:
    wkb = shapely.to_wkb([shapely.transform(g, lambda xy: xy + ORIGIN) for g in geometries])  # local -> global
    data = {"fid": pa.array(fids, pa.int64()), **columns, "geometry": pa.array(list(wkb), pa.binary())}
    pyogrio.write_arrow(
        pa.table(data), path, layer=layer, driver="GPKG", geometry_name="geometry", geometry_type=geometry_type, crs=CRS
    )


def write_map(maps_root: Path, location: str = LOCATION, version: str = MAP_VERSION) -> Path:
    """Write the network to ``maps_root/<location>/<version>/map.gpkg`` and return the file's path."""
    path = Path(maps_root) / location / version / "map.gpkg"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.unlink(missing_ok=True)
    _write(
        path,
        "lanes_polygons",
        [lane.fid for lane in LANES],
        [lane_polygon(lane) for lane in LANES],
        "Polygon",
        lane_group_fid=[lane.parent for lane in LANES],
        lane_index=[lane.index for lane in LANES],
        speed_limit_mps=[lane.speed_limit for lane in LANES],
    )
    _write(path, "lane_groups_polygons", *_boxes(ROADBLOCKS), "Polygon")
    connectors = [lc.fid for lc in LANE_CONNECTORS]
    _write(
        path,
        "lane_connectors",
        connectors,
        [shapely.LineString(lc.centerline) for lc in LANE_CONNECTORS],
        "LineString",
        lane_group_connector_fid=[lc.parent for lc in LANE_CONNECTORS],
        exit_lane_fid=[lc.from_lane for lc in LANE_CONNECTORS],
        entry_lane_fid=[lc.to_lane for lc in LANE_CONNECTORS],
        speed_limit_mps=[lc.speed_limit for lc in LANE_CONNECTORS],
    )
    _write(
        path,
        "gen_lane_connectors_scaled_width_polygons",
        [3000 + i for i in range(len(LANE_CONNECTORS))],
        [lane_polygon(lc) for lc in LANE_CONNECTORS],
        "Polygon",
        lane_connector_fid=connectors,
    )
    rbc_ids = list(ROADBLOCK_CONNECTORS)
    rbc_polygons = [
        shapely.union_all([lane_polygon(lc) for lc in LANE_CONNECTORS if lc.parent == fid]) for fid in rbc_ids
    ]
    _write(
        path,
        "lane_group_connectors",
        rbc_ids,
        [shapely.convex_hull(p) for p in rbc_polygons],
        "Polygon",
        from_lane_group_fid=[ROADBLOCK_CONNECTORS[fid][0] for fid in rbc_ids],
        to_lane_group_fid=[ROADBLOCK_CONNECTORS[fid][1] for fid in rbc_ids],
    )
    every = LANES + LANE_CONNECTORS
    _write(
        path,
        "baseline_paths",
        [4000 + i for i in range(len(every))],
        [shapely.LineString(lane.centerline) for lane in every],
        "LineString",
        lane_fid=[lane.fid if lane.from_lane is None else None for lane in every],
        lane_connector_fid=[lane.fid if lane.from_lane is not None else None for lane in every],
    )
    _write(path, "intersections", *_boxes(INTERSECTIONS), "Polygon")
    _write(path, "carpark_areas", *_boxes(CARPARKS), "Polygon")
    _write(path, "walkways", *_boxes(WALKWAYS), "Polygon")
    return path
