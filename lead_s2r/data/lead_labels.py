"""LEAD's CARLA label spaces built from our schema's: the 13 BEV semantic classes and the 8 box classes of LEAD's
CARLA heads (LEAD ``lead/common/constants.py``: ``TransfuserBEVSemanticClass``, ``TransfuserBoundingBoxClass``; the
loader ``lead/data_loader/carla_dataset.py`` with ``carla_dataset_utils.build_bev_occupancy`` and
``get_bbox_labels``, LEAD commit 4489176).

LEAD's BEV label is the hdmap with ChauffeurNet ids remapped (sidewalks and the hdmap's traffic-light colours become
unlabelled, both lane-marker kinds one class), then an occupancy raster drawn from the boxes laid over it: each box's
rotated footprint filled with its class, later boxes over earlier ones; pedestrians and bikers are drawn 2.5 times
their size with half extents of at least 0.4 m. LEAD has two modes, and so do we: the leaderboard mode (a CARLA-only
network) keeps emergency vehicles as special vehicles and cones and warnings as obstacles; sim-to-real (a network
that also reads real data) applies LEAD's ``SIM2REAL_*`` converters: special vehicles are vehicles, obstacles are not
drawn into the BEV, stop-sign areas are unlabelled.

Traffic lights follow LEAD too, from the adapter's ``traffic_light_states`` and ``traffic_light_affects_ego``
extras (:func:`traffic_light_classes`): only red or yellow lights that affect the ego are detected; every light that
affects the ego is drawn into the BEV in its state's class, and the convex hull of all such lights' corners of the
first state present among unusual red, red, green is filled after every box. Only construction cones and traffic
warnings (our ``CZONE_SIGN``) are LEAD obstacles; LEAD neither detects nor draws other traffic cones.

What our schema does not record is left out: stop signs' ``affects_ego``, parked cars and scenario obstacles (LEAD's
PARKING and its scenario relabelling, construction-site and accident hulls), LEAD's size table for cones, warnings
and parked-car meshes, and LEAD's LiDAR-hit visibility filter.
"""

import math
from dataclasses import dataclass
from enum import IntEnum
from functools import lru_cache
from typing import Any

import cv2
import numpy as np

from lead_s2r.geometry import raster_lookup
from lead_s2r.models.config import BEVGrid
from lead_s2r.models.inputs import IGNORE_CLASS
from lead_s2r.schema import BevClassCarla, BoxClass


class LeadBevClass(IntEnum):
    """LEAD's ``TransfuserBEVSemanticClass``: the channels of the CARLA BEV semantic head."""

    UNLABELED = 0
    ROAD = 1
    LANE_MARKERS = 2
    STOP_SIGNS = 3
    VEHICLE = 4
    WALKER = 5
    OBSTACLE = 6
    PARKING_VEHICLE = 7
    SPECIAL_VEHICLE = 8
    BIKER = 9
    TRAFFIC_GREEN = 10
    TRAFFIC_RED_NORMAL = 11
    TRAFFIC_RED_NOT_NORMAL = 12


class LeadBoxClass(IntEnum):
    """LEAD's ``TransfuserBoundingBoxClass``: the heatmap channels of the CARLA CenterNet head."""

    VEHICLE = 0
    WALKER = 1
    TRAFFIC_LIGHT = 2
    STOP_SIGN = 3
    SPECIAL = 4
    OBSTACLE = 5
    PARKING = 6
    BIKER = 7


#: LEAD's ``CHAFFEURNET_TO_TRANSFUSER_BEV_SEMANTIC_CONVERTER``.
HDMAP_TO_LEAD = {
    BevClassCarla.UNLABELED: LeadBevClass.UNLABELED,
    BevClassCarla.ROAD: LeadBevClass.ROAD,
    BevClassCarla.SIDEWALK: LeadBevClass.UNLABELED,
    BevClassCarla.LANE_MARKERS: LeadBevClass.LANE_MARKERS,
    BevClassCarla.LANE_MARKERS_BROKEN: LeadBevClass.LANE_MARKERS,
    BevClassCarla.STOP_SIGNS: LeadBevClass.STOP_SIGNS,
    BevClassCarla.TRAFFIC_GREEN: LeadBevClass.UNLABELED,
    BevClassCarla.TRAFFIC_YELLOW: LeadBevClass.UNLABELED,
    BevClassCarla.TRAFFIC_RED: LeadBevClass.UNLABELED,
}
#: Our box class -> LEAD's, leaderboard mode; classes LEAD does not detect (barriers, other static objects) absent.
BOX_TO_LEAD = {
    BoxClass.VEHICLE: LeadBoxClass.VEHICLE,
    BoxClass.PEDESTRIAN: LeadBoxClass.WALKER,
    BoxClass.BICYCLE: LeadBoxClass.BIKER,
    BoxClass.CZONE_SIGN: LeadBoxClass.OBSTACLE,
    BoxClass.TRAFFIC_LIGHT: LeadBoxClass.TRAFFIC_LIGHT,
    BoxClass.STOP_SIGN: LeadBoxClass.STOP_SIGN,
    BoxClass.EMERGENCY_VEHICLE: LeadBoxClass.SPECIAL,
}
#: Our box class -> the BEV class LEAD draws its footprint with, leaderboard mode.
BOX_TO_LEAD_BEV = {
    BoxClass.VEHICLE: LeadBevClass.VEHICLE,
    BoxClass.PEDESTRIAN: LeadBevClass.WALKER,
    BoxClass.BICYCLE: LeadBevClass.BIKER,
    BoxClass.CZONE_SIGN: LeadBevClass.OBSTACLE,
    BoxClass.EMERGENCY_VEHICLE: LeadBevClass.SPECIAL_VEHICLE,
}
#: LEAD's ``SIM2REAL_*`` converters on top of the leaderboard tables (None: not drawn / unlabelled).
SIM2REAL_BOX = {LeadBoxClass.SPECIAL: LeadBoxClass.VEHICLE, LeadBoxClass.PARKING: LeadBoxClass.VEHICLE}
SIM2REAL_BEV = {
    LeadBevClass.STOP_SIGNS: LeadBevClass.UNLABELED,
    LeadBevClass.OBSTACLE: LeadBevClass.UNLABELED,
    LeadBevClass.PARKING_VEHICLE: LeadBevClass.VEHICLE,
    LeadBevClass.SPECIAL_VEHICLE: LeadBevClass.VEHICLE,
    LeadBevClass.TRAFFIC_RED_NOT_NORMAL: LeadBevClass.TRAFFIC_RED_NORMAL,
}
#: The BEV classes of red lights LEAD detects as boxes.
RED_BEV_CLASSES = (LeadBevClass.TRAFFIC_RED_NORMAL, LeadBevClass.TRAFFIC_RED_NOT_NORMAL)
#: Half the side of LEAD's occupancy canvas (``build_bev_occupancy``: 256 m around the ego), metres.
OCCUPANCY_HALF_M = 128.0
#: LEAD's ``scale_pedestrian_bev_semantic_size`` and ``pedestrian_bev_min_extent`` (half extent, metres).
PEDESTRIAN_BEV_SCALE, PEDESTRIAN_BEV_MIN_HALF_EXTENT = 2.5, 0.4


#: LEAD's red-light states (``affects_ego`` lights in any other state are drawn green).
RED_STATES = ("Red", "Yellow")


def traffic_light_classes(classes: np.ndarray, extras: dict[str, Any]) -> np.ndarray:
    """(N,) per box the :class:`LeadBevClass` a traffic light affecting the ego is drawn with (green, red, or red of
    an unusual kind), ``UNLABELED`` for a light that does not affect the ego (or whose state the data lacks), -1 for
    every other box. ``extras``: the sample's ``carla_lead`` extras, lights listed in box order."""
    out = np.full(len(classes), -1, np.int64)
    lights = np.flatnonzero(np.asarray(classes) == BoxClass.TRAFFIC_LIGHT)
    states = extras.get("traffic_light_states", [])
    affects = extras.get("traffic_light_affects_ego", [False] * len(lights))
    red = (
        LeadBevClass.TRAFFIC_RED_NOT_NORMAL if extras.get("unusual_traffic_lights") else LeadBevClass.TRAFFIC_RED_NORMAL
    )
    for row, state, affecting in zip(lights.tolist(), states, affects, strict=True):
        if not affecting:
            out[row] = LeadBevClass.UNLABELED
        else:
            out[row] = red if state in RED_STATES else LeadBevClass.TRAFFIC_GREEN
    return out


def lead_box_classes(classes: np.ndarray, leaderboard: bool, lights: np.ndarray) -> np.ndarray:
    """(N,) our :class:`~lead_s2r.schema.BoxClass` ids -> LEAD's :class:`LeadBoxClass` ids; -1 where LEAD detects
    no such object (``lights``: :func:`traffic_light_classes`; LEAD detects red lights that affect the ego only)."""
    lookup = _box_table(leaderboard)
    classes = np.asarray(classes, np.int64)
    known = (classes >= 0) & (classes < len(BoxClass))
    unseen_light = (classes == BoxClass.TRAFFIC_LIGHT) & ~is_one_of(lights, RED_BEV_CLASSES)
    return np.where(known & ~unseen_light, lookup[np.clip(classes, 0, len(BoxClass) - 1)], -1)


def is_one_of(values: np.ndarray, choices: tuple[int, ...]) -> np.ndarray:
    """(N,) whether each value equals one of a few ``choices``: ``np.isin`` for a handful of boxes and two choices
    costs three times these comparisons (it sorts or builds a table first)."""
    found = np.zeros(np.shape(values), bool)
    for choice in choices:
        found |= values == choice
    return found


@lru_cache(maxsize=2)
def _box_table(leaderboard: bool) -> np.ndarray:
    """Our box class -> LEAD's box class (-1: none), for the leaderboard or sim-to-real; built once (read-only)."""
    lookup = np.full(len(BoxClass), -1, np.int64)
    for ours, lead in BOX_TO_LEAD.items():
        lookup[ours] = lead if leaderboard else SIM2REAL_BOX.get(lead, lead)
    lookup.flags.writeable = False
    return lookup


#: LEAD's radar-detection class order among equally fast boxes (``parse_radar_detection_labels``); others after.
RADAR_PRIORITY = (
    LeadBoxClass.SPECIAL,
    LeadBoxClass.VEHICLE,
    LeadBoxClass.WALKER,
    LeadBoxClass.OBSTACLE,
    LeadBoxClass.PARKING,
)


#: LEAD box class -> its rank in :data:`RADAR_PRIORITY` (unlisted: last).
_RADAR_RANK = np.full(len(LeadBoxClass), len(RADAR_PRIORITY), np.int64)
_RADAR_RANK[list(RADAR_PRIORITY)] = np.arange(len(RADAR_PRIORITY))
_RADAR_RANK.flags.writeable = False


def radar_priority(lead_classes: np.ndarray) -> np.ndarray:
    """(N,) rank of each LEAD box class in :data:`RADAR_PRIORITY` (classes not listed rank last): one lookup in
    :data:`_RADAR_RANK`, not a Python loop over the boxes."""
    classes = np.asarray(lead_classes, np.int64)
    listed = (classes >= 0) & (classes < len(_RADAR_RANK))
    return np.where(listed, _RADAR_RANK[np.clip(classes, 0, len(_RADAR_RANK) - 1)], len(RADAR_PRIORITY))


def lead_bev_labels(
    hdmap: np.ndarray, boxes: np.ndarray, grid: BEVGrid, leaderboard: bool, lights: np.ndarray
) -> np.ndarray:
    """LEAD's 13-class BEV label on ``grid``: ``hdmap`` (our :class:`~lead_s2r.schema.BevClassCarla` ids on the grid,
    :data:`IGNORE_CLASS` outside the stored raster) remapped, with the boxes' (N, 10) footprints drawn over it in
    order, then the hull of the traffic lights affecting the ego (``lights``: :func:`traffic_light_classes`).

    ``hdmap`` is uint8: the remap is one ``cv2.LUT`` (numpy's ``lookup[hdmap]`` widens the 123k indices to int64
    first, 10x slower), and LEAD's layout is a ``cv2.rotate`` either way (a quarter turn: ``labels.T[::-1]``). From
    a stored raster, :func:`lead_hdmap_canvas` and :func:`draw_lead_boxes` do the same."""
    _, lookup, _ = _bev_tables(leaderboard)
    canvas = cv2.rotate(cv2.LUT(hdmap, lookup), cv2.ROTATE_90_COUNTERCLOCKWISE)
    return draw_lead_boxes(canvas, boxes, grid, leaderboard, lights)


def lead_hdmap_canvas(raster: np.ndarray, spec: dict[str, Any], grid: BEVGrid, leaderboard: bool) -> np.ndarray:
    """``cv2.rotate(cv2.LUT(bev_labels(raster, spec, grid), lookup), cv2.ROTATE_90_COUNTERCLOCKWISE)``, the first
    step of :func:`lead_bev_labels` from a stored hdmap raster, as one gather: the remap applied to the raster's
    pixels (fewer than the grid's cells) and the quarter turn to the cached gather index."""
    return bev_labels(raster, spec, grid, _bev_tables(leaderboard)[1], quarter_turn=True)


def draw_lead_boxes(
    canvas: np.ndarray, boxes: np.ndarray, grid: BEVGrid, leaderboard: bool, lights: np.ndarray
) -> np.ndarray:
    """The rest of :func:`lead_bev_labels`: the boxes drawn into LEAD's remapped hdmap ``canvas`` in LEAD's layout
    (written in place), returned in ours."""
    convert, _, bev_class = _bev_tables(leaderboard)
    boxes = np.asarray(boxes, np.float64).reshape(-1, 10)
    ours = boxes[:, 9].astype(np.int64)
    known = (ours >= 0) & (ours < len(BoxClass))
    drawn_class = np.where(lights >= 0, lights, bev_class[np.where(known, ours, 0)])
    drawn = np.flatnonzero(known & (drawn_class != LeadBevClass.UNLABELED) & _on_occupancy_canvas(boxes, grid))
    corners = _footprint_pixels(boxes[drawn], grid)
    labels = convert[drawn_class[drawn]].tolist()
    # fillPoly draws nothing outside the polygon's corners: a footprint off the canvas is not drawn (the hull below
    # still takes its corners)
    low, high = corners.min(axis=1), corners.max(axis=1)
    touches = (high[:, 0] >= 0) & (low[:, 0] < canvas.shape[1]) & (high[:, 1] >= 0) & (low[:, 1] < canvas.shape[0])
    for index in np.flatnonzero(touches).tolist():
        cv2.fillPoly(canvas, [corners[index]], labels[index])
    for light in (LeadBevClass.TRAFFIC_RED_NOT_NORMAL, LeadBevClass.TRAFFIC_RED_NORMAL, LeadBevClass.TRAFFIC_GREEN):
        of_light = drawn_class[drawn] == light
        if of_light.any():  # LEAD fills the hull of one kind only, the first present in this order
            cv2.fillPoly(canvas, [cv2.convexHull(corners[of_light].reshape(-1, 2))], int(convert[light]))
            break
    return cv2.rotate(canvas, cv2.ROTATE_90_CLOCKWISE)


@lru_cache(maxsize=2)
def _bev_tables(leaderboard: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """LEAD's BEV class remap (LEAD's class -> the trained class), our hdmap id -> that class (uint8, 256 entries,
    :data:`IGNORE_CLASS` for unknown ids) and our box class -> LEAD's BEV class, for the leaderboard or sim-to-real."""
    convert = np.arange(256, dtype=np.int64)
    if not leaderboard:
        for lead, sim2real in SIM2REAL_BEV.items():
            convert[lead] = sim2real
    lookup = np.full(256, IGNORE_CLASS, np.uint8)
    for ours, lead in HDMAP_TO_LEAD.items():
        lookup[ours] = convert[lead]
    bev_class = np.full(len(BoxClass), int(LeadBevClass.UNLABELED), np.int64)
    for ours, lead in BOX_TO_LEAD_BEV.items():
        bev_class[ours] = lead
    for table in (convert, lookup, bev_class):
        table.flags.writeable = False  # shared by every call
    return convert, lookup, bev_class


def _footprint_pixels(boxes: np.ndarray, grid: BEVGrid) -> np.ndarray:
    """(N, 4, 2) int32 corners of the boxes' footprints as LEAD draws them, in LEAD's layout of ``grid`` (column
    along x, row along y right): ``cv2.boxPoints`` of the box on LEAD's 256 m occupancy canvas, truncated to
    integers there and then cropped to the grid, so every vertex is LEAD's; pedestrians and bikers grown as LEAD
    draws them. (A vertex computed on the grid itself would truncate the other way left of it.)"""
    centre, half = footprint_rects(boxes, grid)
    points = box_points(centre, half * 2 * grid.pixels_per_meter, np.rad2deg(-boxes[:, 6]))
    return points.astype(np.int32) - canvas_crop(grid)


def box_points(centres: np.ndarray, sizes: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """(N, 4, 2) float32 corners of N rotated rectangles, bit for bit ``cv2.boxPoints(((cx, cy), (w, h), angle))``
    of each (tests/test_transform_speed.py), in one pass instead of a call per box.

    OpenCV's arithmetic, written out: the rectangle held in float32, the angle's cosine and sine taken in double
    (``math``: the C library's, as OpenCV's) and halved in float32, and every corner formed from the centre in
    float32 in OpenCV's order of operations."""
    centre, size = np.asarray(centres, np.float32), np.asarray(sizes, np.float32)
    radians = [angle * math.pi / 180.0 for angle in np.asarray(angles_deg, np.float32).tolist()]
    half_cos = np.array([math.cos(r) for r in radians], np.float32) * np.float32(0.5)
    half_sin = np.array([math.sin(r) for r in radians], np.float32) * np.float32(0.5)
    cx, cy, width, height = centre[:, 0], centre[:, 1], size[:, 0], size[:, 1]
    corners = np.empty((len(centre), 4, 2), np.float32)
    corners[:, 0, 0] = cx - half_sin * height - half_cos * width
    corners[:, 0, 1] = cy + half_cos * height - half_sin * width
    corners[:, 1, 0] = cx + half_sin * height - half_cos * width
    corners[:, 1, 1] = cy - half_cos * height - half_sin * width
    corners[:, 2, 0] = cx + half_sin * height + half_cos * width
    corners[:, 2, 1] = cy - half_cos * height + half_sin * width
    corners[:, 3, 0] = cx - half_sin * height + half_cos * width
    corners[:, 3, 1] = cy + half_cos * height + half_sin * width
    return corners


def footprint_rects(boxes: np.ndarray, grid: BEVGrid) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) centres of the boxes on LEAD's occupancy canvas (pixels) and (N, 2) half extents (metres), pedestrians
    and bikers grown as LEAD draws them."""
    half = boxes[:, 3:5] / 2
    grown = is_one_of(boxes[:, 9], (BoxClass.PEDESTRIAN, BoxClass.BICYCLE))
    half[grown] = np.maximum(half[grown], PEDESTRIAN_BEV_MIN_HALF_EXTENT) * PEDESTRIAN_BEV_SCALE
    centre = np.stack([boxes[:, 0] + OCCUPANCY_HALF_M, OCCUPANCY_HALF_M - boxes[:, 1]], axis=1) * grid.pixels_per_meter
    return centre, half


def canvas_crop(grid: BEVGrid) -> np.ndarray:
    """(2,) int32 pixel offset of ``grid``'s corner on LEAD's occupancy canvas."""
    ppm = grid.pixels_per_meter
    crop = np.array([OCCUPANCY_HALF_M * ppm + grid.x_min * ppm, OCCUPANCY_HALF_M * ppm - grid.y_max * ppm]).astype(int)
    return crop.astype(np.int32)


def _on_occupancy_canvas(boxes: np.ndarray, grid: BEVGrid) -> np.ndarray:
    """(N,) whether each box's centre lies on LEAD's occupancy canvas (LEAD skips the others)."""
    centre, _ = footprint_rects(boxes, grid)
    return ((centre >= 0) & (centre < 2 * OCCUPANCY_HALF_M * grid.pixels_per_meter)).all(axis=1)


def bev_labels(
    labels: np.ndarray,
    spec: dict[str, Any],
    grid: BEVGrid,
    lookup: np.ndarray | None = None,
    quarter_turn: bool = False,
) -> np.ndarray:
    """Class ids (uint8) of a stored BEV raster (``meta.bev`` spec) at ``grid``'s cell centres, :data:`IGNORE_CLASS`
    outside it; the ids (and :data:`IGNORE_CLASS`) mapped through the uint8 ``lookup`` where given, and turned a
    quarter counterclockwise (``cv2.ROTATE_90_COUNTERCLOCKWISE``) with ``quarter_turn``.

    The nearest-pixel lookup depends only on the spec, the raster's shape and the grid, so it is computed once
    (:func:`bev_gather`) and each sample is one gather: the raster's uint8 values with a last row and column of the
    fill, remapped, then gathered by the cached :class:`BevGather`."""
    pixel_to_ego = tuple(tuple(float(v) for v in row) for row in spec["pixel_to_ego"])
    gather = bev_gather(pixel_to_ego, labels.shape[:2], grid, quarter_turn)
    h, w = labels.shape[:2]
    padded = np.empty((h + 1, w + 1), np.uint8)
    padded[:h, :w] = labels
    padded[h], padded[:, w] = IGNORE_CLASS, IGNORE_CLASS  # where the gather points for cells outside the raster
    if lookup is not None:
        cv2.LUT(padded, lookup, dst=padded)
    return gather(padded)


@dataclass(frozen=True)
class BevGather:
    """Where each grid cell reads a stored raster padded with a fill row and column (index h or w: outside).

    Where the raster's rows run along the grid's columns and its columns along the grid's rows (LEAD's hdmap in
    LEAD's layout), cell (i, j) reads pixel (``rows[j]``, ``columns[i]``): a copy of rows, then a take of columns,
    half the time of a flat gather, which reads an 8-byte index per cell. Otherwise ``flat`` is the flat index of
    every cell (a separable gather with the axes not swapped was no faster: numpy's column take is slow)."""

    flat: np.ndarray | None = None
    rows: np.ndarray | None = None
    columns: np.ndarray | None = None

    def __call__(self, padded: np.ndarray) -> np.ndarray:
        if self.flat is not None:
            return padded.reshape(-1)[self.flat]
        return padded[self.rows].T.take(self.columns, axis=0)


@lru_cache(maxsize=64)
def bev_gather(
    pixel_to_ego: tuple[tuple[float, ...], ...], shape: tuple[int, int], grid: BEVGrid, quarter_turn: bool = False
) -> BevGather:
    """The :class:`BevGather` of :func:`bev_gather_index`: by rows and columns where that reads the same pixels."""
    index = bev_gather_index(pixel_to_ego, shape, grid, quarter_turn)
    h, w = shape
    inside = index < h * w
    rows, columns = np.where(inside, index // w, h), np.where(inside, index % w, w)  # pixel read, (h, w) outside
    flat = rows * (w + 1) + columns
    separable = BevGather(rows=rows.min(axis=0), columns=columns.min(axis=1))  # a real pixel where any cell has one
    read = separable(np.arange((h + 1) * (w + 1)).reshape(h + 1, w + 1))  # the flat pixel each cell reads
    read_outside = (read // (w + 1) == h) | (read % (w + 1) == w)  # read the fill: the same as the flat index's
    gather = separable if np.array_equal(np.where(read_outside, h * (w + 1) + w, read), flat) else BevGather(flat=flat)
    for array in (gather.flat, gather.rows, gather.columns):
        if array is not None:
            array.flags.writeable = False  # shared by every sample
    return gather


@lru_cache(maxsize=64)
def bev_gather_index(
    pixel_to_ego: tuple[tuple[float, ...], ...], shape: tuple[int, int], grid: BEVGrid, quarter_turn: bool = False
) -> np.ndarray:
    """(H, W) flat index into a raster of ``shape`` of every grid cell; ``shape[0] * shape[1]`` (one past the end)
    outside it. :func:`~lead_s2r.geometry.raster_lookup` of a raster of flat indices, so both agree by construction;
    with ``quarter_turn`` laid out in LEAD's layout, (W, H), as ``cv2.ROTATE_90_COUNTERCLOCKWISE`` turns it."""
    xs, ys = bev_cell_centres(grid)
    x, y = np.meshgrid(xs, ys, indexing="ij")
    size = shape[0] * shape[1]
    index = raster_lookup(np.arange(size).reshape(shape), np.asarray(pixel_to_ego), x, y, fill=size)
    if quarter_turn:
        index = np.ascontiguousarray(np.rot90(index))
    index.flags.writeable = False  # shared by every sample
    return index


def bev_cell_centres(grid: BEVGrid, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Ego x (rows) and y (columns) of the cell centres of ``grid`` at ``stride``."""
    h, w = grid.shape
    cell = stride / grid.pixels_per_meter
    xs = grid.x_min + (np.arange(h // stride) + 0.5) * cell
    ys = grid.y_min + (np.arange(w // stride) + 0.5) * cell
    return xs, ys
