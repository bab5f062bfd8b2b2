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
import pyarrow as pa
import shapely

from lead_s2r.schema import MapKind
from lead_s2r_adapters.navsim_map import NuplanMap, exterior_rings
from lead_s2r_adapters.py123d_arrow import SYNC_FILE, Py123dFormatError, column, read_table, unpack
from lead_s2r_adapters.py123d_frames import MAX_COORDINATE

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
    if not isinstance(meta, dict):
        problem = f"expected a map, got {type(meta).__name__}"
        raise Py123dFormatError(folder / SYNC_FILE, problem, "metadata.map_metadata")
    dataset, location = meta.get("dataset") or log.get("dataset"), meta.get("location") or log.get("location")
    if maps_root is None or not dataset or not location:
        return None
    path = maps_root / str(dataset) / f"{dataset}_{location}.arrow"
    return path if path.is_file() else None


@lru_cache(maxsize=8)
def load_map(path: Path) -> NuplanMap:
    """Every surface the scorer reads, with lane topology; cached, so a worker reads a location once."""
    table = read_table(path)
    ids, layers = _integers(table, path, "object_id"), _integers(table, path, "map_layer")
    wanted = np.isin(layers, [LANE, LANE_GROUP, *SURFACE_KINDS])
    features = [unpack(blob, path, "features") for blob in _blobs(table, path, "features", wanted)]
    try:
        polygons = shapely.from_wkb(_blobs(table, path, "wkb", wanted))
    except shapely.errors.GEOSException as err:
        raise Py123dFormatError(path, f"not a WKB geometry ({err})", "wkb") from None
    ids, layers = ids[wanted], layers[wanted]
    group_fields = {int(i): f for i, layer, f in zip(ids, layers, features, strict=True) if layer == LANE_GROUP}
    connector_groups = {i for i, f in group_fields.items() if f.get("intersection_id") is not None}
    kinds, parents, limits, centerlines, lane_edges, group_edges = [], [], [], {}, [], []
    for object_id, layer, fields in zip(ids.tolist(), layers.tolist(), features, strict=True):
        try:
            kind, parent, limit, centerline, edges = _object(object_id, layer, fields, connector_groups)
        except (KeyError, TypeError, ValueError, IndexError, OverflowError) as err:
            problem = f"map object {object_id}: a field is missing or of a wrong type ({type(err).__name__}: {err})"
            raise Py123dFormatError(path, problem, "features") from None
        kinds.append(kind)
        parents.append(parent)
        limits.append(limit)
        if centerline is not None:
            centerlines[object_id] = centerline
        (lane_edges if layer == LANE else group_edges).extend(edges)
    exteriors = exterior_rings(polygons)
    _check_coordinates(path, ids, exteriors, centerlines)
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


def _check_coordinates(path: Path, ids: np.ndarray, exteriors: list[np.ndarray], centerlines: dict) -> None:
    """Every outline and centreline point finite and within :data:`MAX_COORDINATE` (a damaged double reaches 1e308,
    which overflows the float32 of a sample's map context)."""
    for object_id, outline in zip(ids.tolist(), exteriors, strict=True):
        points = np.concatenate([outline, centerlines.get(object_id, np.zeros((0, 2)))])
        if not (np.abs(points) < MAX_COORDINATE).all():
            problem = f"map object {object_id}: a point is not finite or {MAX_COORDINATE:g} m or more away"
            raise Py123dFormatError(path, problem, "wkb")


def _object(
    object_id: int, layer: int, fields: dict[str, Any], connector_groups: set[int]
) -> tuple[MapKind, int, float, np.ndarray | None, np.ndarray]:
    """One map object's kind, parent lane group, speed limit, centreline (lanes) and connector edges (connectors)."""
    if layer == LANE:
        parent = int(fields.get("lane_group_id") if fields.get("lane_group_id") is not None else -1)
        connector = parent in connector_groups
        limit = np.nan if fields.get("speed_limit_mps") is None else float(fields["speed_limit_mps"])
        centerline = np.asarray(fields["centerline"], np.float64)[:, :2]
        edges = _edges(object_id, fields) if connector else np.zeros((0, 3), np.int64)
        return MapKind.LANE_CONNECTOR if connector else MapKind.LANE, parent, limit, centerline, edges
    if layer == LANE_GROUP:
        connector = object_id in connector_groups
        edges = _edges(object_id, fields) if connector else np.zeros((0, 3), np.int64)
        return MapKind.ROADBLOCK_CONNECTOR if connector else MapKind.ROADBLOCK, -1, np.nan, None, edges
    return SURFACE_KINDS[layer], -1, np.nan, None, np.zeros((0, 3), np.int64)


def _integers(table: pa.Table, path: Path, name: str) -> np.ndarray:
    """An integer column without nulls as int64."""
    values = column(table, path, name).combine_chunks()
    if not pa.types.is_integer(values.type) or values.null_count:
        raise Py123dFormatError(path, f"expected an integer per map object, got {values.type}", name)
    return np.asarray(values.to_numpy(), np.int64)


def _blobs(table: pa.Table, path: Path, name: str, wanted: np.ndarray) -> np.ndarray:
    """The ``wanted`` rows of a binary column without nulls, as an object array of bytes."""
    values = column(table, path, name).combine_chunks().filter(pa.array(wanted))
    if not pa.types.is_binary(values.type) or values.null_count:
        raise Py123dFormatError(path, f"expected bytes per map object, got {values.type}", name)
    return values.to_numpy(zero_copy_only=False)


def _edges(object_id: int, fields: dict[str, Any]) -> np.ndarray:
    """(connector, from, to) rows for every predecessor-successor pair of a connector lane or lane group."""
    pairs = [
        (object_id, int(before), int(after))
        for before in fields.get("predecessor_ids") or []
        for after in fields.get("successor_ids") or []
    ]
    return np.array(pairs, np.int64).reshape(-1, 3)


def route_roadblocks(nuplan_map: NuplanMap, route: np.ndarray) -> list[str]:
    """Lane groups (roadblocks and their connectors) a global route polyline (M, 2) passes, in driving order."""
    blocks = np.isin(nuplan_map.kinds, [MapKind.ROADBLOCK, MapKind.ROADBLOCK_CONNECTOR])
    hits, polygon = nuplan_map.tree.query(shapely.points(route), predicate="intersects")
    order: list[str] = []
    for index in polygon[np.argsort(hits, kind="stable")]:
        if blocks[index] and str(nuplan_map.ids[index]) not in order:
            order.append(str(nuplan_map.ids[index]))
    return order
