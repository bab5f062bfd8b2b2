"""nuPlan GeoPackage maps: loading (once per location and process), STRtree queries, and the per-sample
``scoring.npz`` context and NAVSIM BEV label built from them.

Layers are read with pyogrio's Arrow reader: one GDAL call per layer gives the fids, typed (nullable) columns and
WKB geometry, which shapely 2 decodes in bulk. It is the well-kept path GeoPandas itself uses, with no
GeoPandas/Fiona stack, and unlike hand-rolled sqlite3 + GPKG blob parsing it copes with every GPKG flavour GDAL does.
"""

from dataclasses import dataclass
from functools import lru_cache
from itertools import pairwise
from pathlib import Path

import cv2
import numpy as np
import pyarrow as pa
import shapely

from lead_s2r.errors import UserError
from lead_s2r.geometry import box_corners, points_to_local
from lead_s2r.schema import BevClassNavsim, BoxClass, MapKind

#: Legacy ``map_location`` values of OpenScene pickles -> nuPlan map folder.
LOCATION_ALIASES = {"las_vegas": "us-nv-las-vegas-strip"}


#: kind -> (layer, id column or None for the fid, parent column, speed-limit column); missing optional layers are empty.
POLYGON_LAYERS = {
    MapKind.ROADBLOCK: ("lane_groups_polygons", None, None, None),
    MapKind.LANE: ("lanes_polygons", None, "lane_group_fid", "speed_limit_mps"),
    MapKind.LANE_CONNECTOR: ("gen_lane_connectors_scaled_width_polygons", "lane_connector_fid", None, None),
    MapKind.INTERSECTION: ("intersections", None, None, None),
    MapKind.CARPARK_AREA: ("carpark_areas", None, None, None),
    MapKind.ROADBLOCK_CONNECTOR: ("lane_group_connectors", None, None, None),
    MapKind.WALKWAY: ("walkways", None, None, None),
}
OPTIONAL_LAYERS = {"walkways"}


class MapError(UserError, ValueError):
    """A map file, layer or field is missing or malformed; the message names it."""


class MissingLayer(MapError):
    """A layer the GeoPackage does not hold: an error, unless the layer is optional (a damaged file always is)."""


def resolve_location(location: str) -> str:
    return LOCATION_ALIASES.get(location, location)


def find_map(maps_root: Path, location: str) -> Path:
    """``maps_root/<location>/<version>/map.gpkg``; the highest version when several are present."""
    folder = Path(maps_root) / resolve_location(location)
    candidates = sorted(folder.glob("*/map.gpkg"))
    if not candidates:
        raise MapError(f"no map for location {location!r}: expected {folder}/<version>/map.gpkg")
    return candidates[-1]


def _read_layer(path: Path, layer: str) -> pa.Table:
    import pyogrio  # the navsim extra; imported here so the adapter module loads without it

    try:
        meta, table = pyogrio.read_arrow(path, layer=layer, return_fids=True)
    except pyogrio.errors.DataLayerError as err:
        raise MissingLayer(f"{path}: layer {layer!r} is missing ({err})") from None
    except (pyogrio.errors.DataSourceError, OSError) as err:  # a damaged SQLite file, found opening it or reading
        raise MapError(f"{path}: not a readable GeoPackage ({' '.join(str(err).split())})") from None
    rename = {meta["geometry_name"]: "geometry", meta.get("fid_column") or "OGC_FID": "fid", "OGC_FID": "fid"}
    table = table.rename_columns([rename.get(name, name) for name in table.column_names])
    if "geometry" not in table.column_names:  # damaged GeoPackage metadata loses the geometry column's name
        raise MapError(f"{path}: layer {layer!r} has no geometry column")
    return table


def _column(path: Path, layer: str, table: pa.Table, name: str, fill: float | int = -1) -> np.ndarray:
    if name not in table.column_names:
        raise MapError(f"{path}: layer {layer!r} has no field {name!r}")
    column = table[name]
    dtype = np.float64 if pa.types.is_floating(column.type) else np.int64
    return column.fill_null(fill).to_numpy().astype(dtype)


@dataclass
class NuplanMap:
    """One location's map in global coordinates, with an STRtree over every polygon."""

    path: Path
    polygons: np.ndarray  # shapely polygons (K,)
    ids: np.ndarray  # int64 (K,)
    kinds: np.ndarray  # int8 (K,)
    parents: np.ndarray  # int64 (K,): lane -> roadblock, lane connector -> roadblock connector, else -1
    speed_limits: np.ndarray  # float64 (K,), NaN where none
    tree: shapely.STRtree
    exteriors: list[np.ndarray]  # (R, 2) exterior ring of each polygon (of its convex hull for a multipolygon)
    centerlines: dict[int, np.ndarray]  # lane or lane connector id -> (Q, 2)
    connectors: np.ndarray  # int64 (C, 3): lane connector id, exit lane (from), entry lane (to)
    roadblock_connectors: np.ndarray  # int64 (B, 3): roadblock connector id, from roadblock, to roadblock

    def near(self, xy: np.ndarray, radius: float) -> np.ndarray:
        """Indices of polygons within ``radius`` metres of the global point ``xy``, sorted."""
        return np.sort(self.tree.query(shapely.Point(xy), predicate="dwithin", distance=radius))


@lru_cache(maxsize=8)
def load_map(maps_root: Path, location: str) -> NuplanMap:
    """Read the layers the scorer needs from :func:`find_map`'s file; cached, so each worker process finds and reads
    a location once (pass the resolved location, so an alias does not read the map again)."""
    path = find_map(maps_root, location)
    polygons, ids, kinds, parents, limits = [], [], [], [], []
    connector_info = _read_layer(path, "lane_connectors")
    for kind, (layer, id_field, parent_field, limit_field) in POLYGON_LAYERS.items():
        try:
            table = _read_layer(path, layer)
        except MissingLayer:
            if layer in OPTIONAL_LAYERS:
                continue
            raise
        n = table.num_rows
        polygons.append(shapely.from_wkb(table["geometry"].to_numpy(zero_copy_only=False)))
        ids.append(_column(path, layer, table, id_field or "fid"))
        kinds.append(np.full(n, kind, np.int8))
        if kind is MapKind.LANE_CONNECTOR:
            # a connector's parent and speed limit live in the lane_connectors layer, keyed by its fid
            lookup = {fid: i for i, fid in enumerate(_column(path, "lane_connectors", connector_info, "fid"))}
            rows = np.array([lookup[fid] for fid in ids[-1]], dtype=np.int64)
            parent = _column(path, "lane_connectors", connector_info, "lane_group_connector_fid")[rows]
            limit = _column(path, "lane_connectors", connector_info, "speed_limit_mps", np.nan)[rows]
        else:
            parent = _column(path, layer, table, parent_field) if parent_field else np.full(n, -1, np.int64)
            limit = _column(path, layer, table, limit_field, np.nan) if limit_field else np.full(n, np.nan)
        parents.append(parent)
        limits.append(limit)
    polygons_all = np.concatenate(polygons)
    if not all(isinstance(g, shapely.Polygon | shapely.MultiPolygon) for g in polygons_all):
        raise MapError(f"{path}: a polygon layer holds a geometry that is not a polygon")
    baselines = _read_layer(path, "baseline_paths")
    lane = _column(path, "baseline_paths", baselines, "lane_fid")
    connector = _column(path, "baseline_paths", baselines, "lane_connector_fid")
    lines = shapely.from_wkb(baselines["geometry"].to_numpy(zero_copy_only=False))
    centerlines = {
        int(lane_id if lane_id >= 0 else connector_id): shapely.get_coordinates(line)
        for lane_id, connector_id, line in zip(lane, connector, lines, strict=True)
    }
    rbc = _read_layer(path, "lane_group_connectors")
    return NuplanMap(
        path=path,
        polygons=polygons_all,
        ids=np.concatenate(ids),
        kinds=np.concatenate(kinds),
        parents=np.concatenate(parents),
        speed_limits=np.concatenate(limits),
        tree=shapely.STRtree(polygons_all),
        exteriors=exterior_rings(polygons_all),
        centerlines=centerlines,
        connectors=_edges(path, "lane_connectors", connector_info, ("fid", "exit_lane_fid", "entry_lane_fid")),
        roadblock_connectors=_edges(
            path, "lane_group_connectors", rbc, ("fid", "from_lane_group_fid", "to_lane_group_fid")
        ),
    )


def _edges(path: Path, layer: str, table: pa.Table, names: tuple[str, str, str]) -> np.ndarray:
    """(N, 3) rows of a connector layer: each connector's fid and the fids it connects from and to."""
    return np.column_stack([_column(path, layer, table, name) for name in names])


def exterior_rings(polygons: np.ndarray) -> list[np.ndarray]:
    """The (R, 2) exterior ring of each polygon, of its convex hull for a multipolygon (the scorer reads one ring per
    map object), in one pass over all of them."""
    multi = shapely.get_type_id(polygons) == shapely.GeometryType.MULTIPOLYGON
    rings = shapely.get_exterior_ring(np.where(multi, shapely.convex_hull(polygons), polygons))
    ring_xy, owner = shapely.get_coordinates(rings, return_index=True)
    return _split(ring_xy, np.r_[0, np.cumsum(np.bincount(owner, minlength=len(polygons)))])


def _offsets(groups: list) -> np.ndarray:
    """(K + 1,) int64 offsets of K groups laid end to end."""
    offsets = np.zeros(len(groups) + 1, np.int64)
    offsets[1:] = np.cumsum([len(g) for g in groups])
    return offsets


def _split(points: np.ndarray, offsets: np.ndarray) -> list[np.ndarray]:
    """The K groups of ``points`` delimited by (K + 1,) ``offsets`` (the inverse of laying them end to end)."""
    return [points[start:end] for start, end in pairwise(offsets)]


def _local_ragged(arrays: list[np.ndarray], origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Global (Q_k, 2) point arrays -> concatenated (P, 2) float32 points in the ``origin`` frame and offsets."""
    points = np.concatenate(arrays) if arrays else np.zeros((0, 2))
    return points_to_local(points, origin).astype(np.float32).reshape(-1, 2), _offsets(arrays)


def scoring_context(
    nuplan_map: NuplanMap,
    origin: np.ndarray,
    radius: float,
    route_roadblocks: list[str],
    red_lights: list[list[int]],
    times: np.ndarray,
) -> dict[str, np.ndarray]:
    """The ``scoring.npz`` arrays for a sample whose ego is at the global pose ``origin`` (layout: docs)."""
    index = nuplan_map.near(origin[:2], radius)
    kinds = nuplan_map.kinds[index]
    ids = nuplan_map.ids[index]
    polygon_xy, polygon_offsets = _local_ragged([nuplan_map.exteriors[i] for i in index], origin)
    is_lane = (kinds == MapKind.LANE) | (kinds == MapKind.LANE_CONNECTOR)
    lanes, lane_kinds = ids[is_lane], kinds[is_lane]
    have = [i for i, lane in enumerate(lanes) if int(lane) in nuplan_map.centerlines]
    centerline_xy, centerline_offsets = _local_ragged([nuplan_map.centerlines[int(lanes[i])] for i in have], origin)
    is_connector, is_rbc = kinds == MapKind.LANE_CONNECTOR, kinds == MapKind.ROADBLOCK_CONNECTOR
    connectors = nuplan_map.connectors[np.isin(nuplan_map.connectors[:, 0], ids[is_connector])]
    rbc = nuplan_map.roadblock_connectors[np.isin(nuplan_map.roadblock_connectors[:, 0], ids[is_rbc])]
    return {
        "origin": np.asarray(origin, np.float64),
        "map_radius": np.array(radius, np.float32),
        "polygon_xy": polygon_xy,
        "polygon_offsets": polygon_offsets,
        "polygon_id": ids.astype(np.int64),
        "polygon_kind": kinds.astype(np.int8),
        "polygon_parent": nuplan_map.parents[index].astype(np.int64),
        "polygon_speed_limit": nuplan_map.speed_limits[index].astype(np.float32),
        "centerline_xy": centerline_xy,
        "centerline_offsets": centerline_offsets,
        "centerline_id": lanes[have].astype(np.int64),
        "centerline_kind": lane_kinds[have].astype(np.int8),
        "lane_connector_edges": connectors.astype(np.int64).reshape(-1, 3),
        "roadblock_connector_edges": rbc.astype(np.int64).reshape(-1, 3),
        "route_roadblock_ids": _int_ids(route_roadblocks),
        "red_light_t": np.asarray(times, np.float32),
        "red_light_ids": np.array([i for group in red_lights for i in group], np.int64),
        "red_light_offsets": _offsets(red_lights),
    }


def _int_ids(values: list[str]) -> np.ndarray:
    try:
        return np.array([int(v) for v in values], np.int64)
    except ValueError:
        raise MapError(f"roadblock ids must be integers (nuPlan fids), got {values!r}") from None


# --------------------------------------------------------------------------- BEV label

#: NAVSIM TransFuser's BEV raster: 256 x 256 pixels of 0.25 m, x and y in [-32, 32], forward up, left left.
BEV_SIZE = 256
BEV_RESOLUTION = 0.25
BEV_HALF = BEV_SIZE * BEV_RESOLUTION / 2
BEV_STATIC = {BoxClass.TRAFFIC_CONE, BoxClass.BARRIER, BoxClass.CZONE_SIGN, BoxClass.GENERIC_OBJECT}
BEV_META = {
    "classes": "navsim",
    "size": [BEV_SIZE, BEV_SIZE],
    "resolution": BEV_RESOLUTION,
    "x_range": [-BEV_HALF, BEV_HALF],
    "y_range": [-BEV_HALF, BEV_HALF],
    # pixel (column, row) index -> ego (x, y) of its centre
    "pixel_to_ego": [
        [0.0, -BEV_RESOLUTION, BEV_HALF - BEV_RESOLUTION / 2],
        [-BEV_RESOLUTION, 0.0, BEV_HALF - BEV_RESOLUTION / 2],
    ],
    "layout": "row 0 = x max (forward up), column 0 = y max (left on the left); pixel centre x = x_max - (row+0.5)*res",
}


def _pixels(points: np.ndarray) -> np.ndarray:
    """Ego-frame (N, 2) -> cv2 (column, row) int32 at 1/4 pixel precision (``shift=2``)."""
    col = (BEV_HALF - points[:, 1]) / BEV_RESOLUTION
    row = (BEV_HALF - points[:, 0]) / BEV_RESOLUTION
    return np.round(np.column_stack([col, row]) * 4 - 2).astype(np.int32)


def bev_semantic_raster(context: dict[str, np.ndarray], boxes: np.ndarray) -> np.ndarray:
    """NAVSIM's 7-class label: road (lanes + intersections), walkways, centerlines, then static objects,
    vehicles and pedestrians, later classes painted over earlier ones."""
    bev = np.zeros((BEV_SIZE, BEV_SIZE), np.uint8)
    polygons = _split(_pixels(context["polygon_xy"]), context["polygon_offsets"])
    kinds = context["polygon_kind"]

    def rings(wanted: set[int]) -> list[np.ndarray]:
        return [ring for ring, kind in zip(polygons, kinds, strict=True) if kind in wanted]

    cv2.fillPoly(bev, rings({MapKind.LANE, MapKind.INTERSECTION}), int(BevClassNavsim.ROAD), shift=2)
    cv2.fillPoly(bev, rings({MapKind.WALKWAY}), int(BevClassNavsim.WALKWAYS), shift=2)
    polylines = _split(_pixels(context["centerline_xy"]), context["centerline_offsets"])
    cv2.polylines(bev, polylines, False, int(BevClassNavsim.CENTERLINE), thickness=2, shift=2)
    classes = boxes[:, 9].astype(int)
    for label, wanted in (
        (BevClassNavsim.STATIC_OBJECTS, BEV_STATIC),
        (BevClassNavsim.VEHICLES, {BoxClass.VEHICLE, BoxClass.EMERGENCY_VEHICLE}),
        (BevClassNavsim.PEDESTRIANS, {BoxClass.PEDESTRIAN}),
    ):
        chosen = boxes[np.isin(classes, [int(c) for c in wanted])]
        cv2.fillPoly(bev, [_pixels(c) for c in box_corners(chosen)], int(label), shift=2)
    return bev
