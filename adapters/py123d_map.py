"""123D maps -> the polygons, lanes and connectors of our ``scoring`` context (and from it the NAVSIM BEV label).

A 123D map is one Arrow IPC file (``<root>/maps/<dataset>/<dataset>_<location>.arrow``, or ``map.arrow`` in the log
folder for per-log maps) with one row per map object: ``object_id``, ``map_layer`` (py123d's ``MapLayer``), the
geometry as WKB (decoded in bulk by shapely) and the object's fields as msgpack (lane group, neighbours,
predecessors / successors, centreline, speed limit). We read it into the same :class:`NuplanMap` the NAVSIM adapter
builds from nuPlan GeoPackages, so both share one scoring-context builder and one BEV renderer:

- a lane group is a ROADBLOCK, or a ROADBLOCK_CONNECTOR when it lies in an intersection (``intersection_id``);
- a lane is a LANE, or a LANE_CONNECTOR when its group is a connector; its parent is its lane group;
- intersections, walkways and car parks keep their kind; a generic drivable area counts as CARPARK_AREA (the one
  non-lane drivable kind the scorer knows); crosswalks, stop zones, road edges and lines are not read.
"""

from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from lead_s2r.schema import MapKind
from lead_s2r_adapters.navsim_map import NuplanMap
from lead_s2r_adapters.py123d_arrow import Py123dFormatError, column, read_table, unpack

#: py123d's MapLayer numbers (0.7).
LANE, LANE_GROUP, INTERSECTION, WALKWAY, CARPARK, GENERIC_DRIVABLE = 0, 1, 2, 4, 5, 6
SURFACE_KINDS = {INTERSECTION: MapKind.INTERSECTION, WALKWAY: MapKind.WALKWAY, CARPARK: MapKind.CARPARK_AREA}
SURFACE_KINDS[GENERIC_DRIVABLE] = MapKind.CARPARK_AREA


def find_map(folder: Path, maps_root: Path | None, log: dict[str, Any]) -> Path | None:
    """The log's map file: ``map.arrow`` beside it, else ``<maps_root>/<dataset>/<dataset>_<location>.arrow``."""
    own = folder / "map.arrow"
    if own.is_file():
        return own
    meta = log.get("map_metadata") or {}
    dataset, location = meta.get("dataset") or log.get("dataset"), meta.get("location") or log.get("location")
    if maps_root is None or not dataset or not location:
        return None
    path = maps_root / str(dataset) / f"{dataset}_{location}.arrow"
    return path if path.is_file() else None


@lru_cache(maxsize=8)
def load_map(path: Path) -> NuplanMap:
    """Every surface the scorer reads, with lane topology; cached, so a worker reads a location once."""
    table = read_table(path)
    ids = column(table, path, "object_id").to_numpy().astype(np.int64)
    layers = column(table, path, "map_layer").to_numpy().astype(np.int64)
    wanted = np.isin(layers, [LANE, LANE_GROUP, *SURFACE_KINDS])
    try:
        features = [unpack(blob) for blob in column(table, path, "features").filter(wanted).to_pylist()]
        polygons = shapely.from_wkb(column(table, path, "wkb").filter(wanted).to_numpy(zero_copy_only=False))
    except Exception as err:  # msgpack and GEOS raise many types on corrupt blobs
        raise Py123dFormatError(path, f"map objects are not py123d msgpack + WKB ({err})", "features") from None
    ids, layers = ids[wanted], layers[wanted]
    group_fields = {int(i): f for i, layer, f in zip(ids, layers, features, strict=True) if layer == LANE_GROUP}
    connector_groups = {i for i, f in group_fields.items() if f.get("intersection_id") is not None}
    kinds, parents, limits, centerlines, lane_edges, group_edges = [], [], [], {}, [], []
    for object_id, layer, fields in zip(ids.tolist(), layers.tolist(), features, strict=True):
        parent, limit = -1, np.nan
        if layer == LANE:
            parent = int(fields.get("lane_group_id") if fields.get("lane_group_id") is not None else -1)
            connector = parent in connector_groups
            kinds.append(MapKind.LANE_CONNECTOR if connector else MapKind.LANE)
            limit = np.nan if fields.get("speed_limit_mps") is None else float(fields["speed_limit_mps"])
            centerlines[object_id] = np.asarray(fields["centerline"], np.float64)[:, :2]
            if connector:
                lane_edges += _edges(object_id, fields)
        elif layer == LANE_GROUP:
            connector = object_id in connector_groups
            kinds.append(MapKind.ROADBLOCK_CONNECTOR if connector else MapKind.ROADBLOCK)
            if connector:
                group_edges += _edges(object_id, fields)
        else:
            kinds.append(SURFACE_KINDS[layer])
        parents.append(parent)
        limits.append(limit)
    exteriors = [shapely.get_coordinates(shapely.get_exterior_ring(_one(p)))[:, :2] for p in polygons]
    return NuplanMap(
        path=path,
        polygons=polygons,
        ids=ids,
        kinds=np.array(kinds, np.int8),
        parents=np.array(parents, np.int64),
        speed_limits=np.array(limits, np.float64),
        tree=shapely.STRtree(polygons),
        exteriors=exteriors,
        centerlines=centerlines,
        connectors=np.array(lane_edges, np.int64).reshape(-1, 3),
        roadblock_connectors=np.array(group_edges, np.int64).reshape(-1, 3),
    )


def _one(polygon: Any) -> Any:
    """A polygon, or the convex hull of a multipolygon (the scorer reads one ring per object)."""
    return shapely.convex_hull(polygon) if shapely.get_type_id(polygon) == 6 else polygon


def _edges(object_id: int, fields: dict[str, Any]) -> list[tuple[int, int, int]]:
    """(connector, from, to) for every predecessor-successor pair of a connector lane or lane group."""
    return [
        (object_id, int(before), int(after))
        for before in fields.get("predecessor_ids") or []
        for after in fields.get("successor_ids") or []
    ]


def route_roadblocks(nuplan_map: NuplanMap, route: np.ndarray) -> list[str]:
    """Lane groups (roadblocks and their connectors) a global route polyline (M, 2) passes, in driving order."""
    blocks = np.isin(nuplan_map.kinds, [MapKind.ROADBLOCK, MapKind.ROADBLOCK_CONNECTOR])
    hits, polygon = nuplan_map.tree.query(shapely.points(route), predicate="intersects")
    order: list[str] = []
    for index in polygon[np.argsort(hits, kind="stable")]:
        if blocks[index] and str(nuplan_map.ids[index]) not in order:
            order.append(str(nuplan_map.ids[index]))
    return order
