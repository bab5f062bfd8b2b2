"""Where the ego is on the map, per proposal and step: NAVSIM's ``PDMScorer._calculate_ego_area`` and
``PDMDrivableMap.is_in_layer``. Instead of a loop over polygons, a uniform grid over the polygons' bounding boxes
(:class:`BoundsGrid`, numpy only: no point geometry is built) picks candidate polygons for every point. Each
(cell, polygon) pair is classified once, when a point first falls in it (GEOS on the cell's square grown by
:data:`CELL_MARGIN_M`): the square inside the polygon's interior (every point of the cell is inside), clear of the
polygon (none is), or crossed by its edge. A cell no polygon edge crosses answers all its points at once
(:class:`SettledCells`: the layers and lanes whose interior holds it); only points in crossed cells go on to their
candidates, the bounding-box test and prepared ``shapely.contains_xy``. A point's computed cell is off its true
position by rounding far below the margin, so the grid only decides points whose answer is certain, and the answer
is ``contains_xy``'s for every point.

The map is what ``PDMDrivableMap.from_simulation`` holds: ROADBLOCK, LANE, LANE_CONNECTOR, INTERSECTION and
CARPARK_AREA polygons. ROADBLOCK_CONNECTOR and WALKWAY polygons of the scene are left out, as NAVSIM leaves them out
(a roadblock connector counts only through its lane connectors; nuPlan's DRIVABLE_AREA layer is never queried).
"Inside" is strict (``shapely.vectorized.contains``): a point on a polygon's edge is outside it.

* NON_DRIVABLE_AREA: some corner (of 4; the centre is not checked) lies in no ROADBLOCK, INTERSECTION or CARPARK_AREA.
  Lanes do not count as drivable.
* MULTIPLE_LANES: more than one LANE/LANE_CONNECTOR polygon holds a corner, and none holds all four.
* ONCOMING_TRAFFIC: the box centre lies in no LANE/LANE_CONNECTOR whose id is on the route (``route_lane_ids``).
* INTERSECTION membership of the rear axle (v1.1 TTC, ``is_in_layer``) and of the centre (v2's DDC/LK exclusions).
"""

from dataclasses import dataclass, field
from functools import reduce

import numpy as np
import shapely
from numba import njit

from lead_s2r.schema import MapKind
from lead_s2r.scoring.pdm.footprint import Corner
from lead_s2r.scoring.pdm.scene import PDMScene, ragged_polygons

SCORED_KINDS = (MapKind.ROADBLOCK, MapKind.LANE, MapKind.LANE_CONNECTOR, MapKind.INTERSECTION, MapKind.CARPARK_AREA)
DRIVABLE_KINDS = (MapKind.ROADBLOCK, MapKind.INTERSECTION, MapKind.CARPARK_AREA)
LANE_KINDS = (MapKind.LANE, MapKind.LANE_CONNECTOR)
NUM_CORNERS = 4


#: Membership of every MapKind code in the kinds as lookup tables (``table[codes]``)
IS_DRIVABLE = np.isin(np.arange(max(MapKind) + 1), DRIVABLE_KINDS)
IS_LANE = np.isin(np.arange(max(MapKind) + 1), LANE_KINDS)
#: [m] side of a grid cell: about a lane's width, so most cells list one or two polygons per layer.
GRID_CELL_M = 2.0
#: [m] a cell's square is grown by this before it is classified: far above the rounding of a point's cell
#: (~1e-9 m at UTM coordinates), far below any map feature
CELL_MARGIN_M = 1e-6
#: Fine cells per side of the blocks a cell's polygons are first classified on (``DrivableMap._classify``): a block
#: inside or clear of a polygon answers its cells without a GEOS call each.
BLOCK_CELLS = 4
#: How a cell lies against a polygon (``DrivableMap.cover``): not yet known, clear of it, inside it, crossed by it.
UNKNOWN, CLEAR, INSIDE, CROSSED = -1, 0, 1, 2
#: Grid cells per axis at most (a map's extent over its cell size; bounds the index for huge maps).
MAX_GRID_CELLS = 256
#: (cell size [m], cells per axis at most) of a map scored for a whole vocabulary: built once for millions of points,
#: so finer cells, where fewer points fall into cells a polygon edge crosses, repay their larger index (0.5 m: 12%
#: less time per entry than 2 m in ``benchmarks/vocab_score.py``; 0.25 m is slower again)
VOCABULARY_GRID = (0.5, 1024)


@dataclass
class BoundsGrid:
    """Which boxes ``(K, 4)`` (xmin, ymin, xmax, ymax) reach each cell of a uniform grid, as CSR (``starts``,
    ``members``): a point's cell lists every box that holds it (and a few that do not). A point's cell is
    ``floor((x - origin) / cell)`` computed the same way as a box's cell range, and that is monotone in x under
    rounding, so a box's range always covers the cells of the points it holds."""

    origin: np.ndarray  # (2,)
    cell: float
    shape: tuple[int, int]
    starts: np.ndarray  # (cells + 2,): cell c's members are [starts[c], starts[c + 1]); the last cell is empty
    members: np.ndarray  # (sum of cells per box,) box index
    member_cells: np.ndarray  # (sum of cells per box,) the flat cell of each member entry

    @classmethod
    def build(cls, boxes: np.ndarray, cell: float, max_cells: int = MAX_GRID_CELLS) -> "BoundsGrid":
        """The grid of cell size ``cell`` (or coarser: at most ``max_cells`` per axis) over boxes ``(K, 4)``; boxes
        with non-finite bounds (empty polygons) hold no point and are left out."""
        kept = np.flatnonzero(np.isfinite(boxes).all(axis=1))
        boxes = boxes[kept]
        origin = boxes[:, :2].min(axis=0) if len(boxes) else np.zeros(2)
        top = boxes[:, 2:].max(axis=0) if len(boxes) else np.zeros(2)
        cell = max(cell, float((top - origin).max()) / max_cells)
        shape = tuple(int(n) + 1 for n in cls._cells(origin, cell, top))
        low, high = cls._cells(origin, cell, boxes[:, :2]), cls._cells(origin, cell, boxes[:, 2:])
        spans = high - low + 1
        box_of = np.repeat(np.arange(len(boxes)), spans.prod(axis=1))
        first = np.cumsum(spans.prod(axis=1)) - spans.prod(axis=1)
        local = np.arange(len(box_of)) - first[box_of]
        column = low[box_of, 0] + local // spans[box_of, 1]
        flat = column * shape[1] + low[box_of, 1] + local % spans[box_of, 1]
        order = np.argsort(flat, kind="stable")
        # one more (empty) cell after the last: where points off the grid look
        starts = np.searchsorted(flat[order], np.arange(shape[0] * shape[1] + 2))
        return cls(origin, cell, shape, starts, kept[box_of[order]], flat[order])

    @staticmethod
    def _cells(origin: np.ndarray, cell: float, xy: np.ndarray) -> np.ndarray:
        return np.floor((xy - origin) / cell).astype(np.int64)

    def cells_of(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The flat cell of each point ``(x, y)``, each ``(B,)``; points off the grid (or NaN) get the empty cell
        after the last."""
        x, y = np.ascontiguousarray(x, np.float64), np.ascontiguousarray(y, np.float64)
        return _cells_of(x, y, float(self.origin[0]), float(self.origin[1]), self.cell, *self.shape)

    def expand(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(position, entry)``: every member entry of each of ``cells``, grouped by position in ``cells``."""
        first = self.starts[cells]
        counts = self.starts[cells + 1] - first
        ends = np.cumsum(counts)
        # entry j of the expansion is first[point] + (j - the expansion's start for that point)
        return np.repeat(np.arange(len(cells)), counts), np.arange(ends[-1] if len(ends) else 0) + np.repeat(
            first - (ends - counts), counts
        )

    def candidates(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(point, entry)`` pairs for points ``(x, y)``, each ``(B,)``, grouped by point in increasing order:
        ``members[entry]`` is a superset of the boxes that hold each point (none for points outside the grid, which
        lie outside every box)."""
        return self.expand(self.cells_of(x, y))

    def squares(self, entries: np.ndarray, margin: float, block: int = 1) -> np.ndarray:
        """Shapely boxes of the cells of member ``entries``, grown by ``margin``; with ``block``, of the blocks of
        ``block`` x ``block`` cells that hold them."""
        column, row = np.divmod(self.member_cells[entries], self.shape[1])
        column, row = column - column % block, row - row % block
        x, y = self.origin[0] + self.cell * column, self.origin[1] + self.cell * row
        side = self.cell * block
        return shapely.box(x - margin, y - margin, x + side + margin, y + side + margin)

    def blocks(self, entries: np.ndarray, block: int) -> np.ndarray:
        """The block of ``block`` x ``block`` cells that holds the cell of each member entry, as one flat index."""
        column, row = np.divmod(self.member_cells[entries], self.shape[1])
        return (column // block) * (self.shape[1] // block + 1) + row // block


@dataclass
class DrivableMap:
    """The scene's scored polygons (kinds in :data:`SCORED_KINDS`, prepared) with their ids, kinds and bounding
    boxes, and a grid over those boxes: a point finds every polygon it can lie in without building its geometry."""

    polygons: np.ndarray  # (K,) shapely Polygons
    ids: np.ndarray  # (K,) int64
    kinds: np.ndarray  # (K,) MapKind codes
    grid: BoundsGrid
    bounds: np.ndarray  # (4, K) rows xmin, ymin, xmax, ymax (gathers by polygon stay 1-D)
    cover: np.ndarray  # per grid entry: how its cell lies against its polygon (UNKNOWN until a point falls in it)
    settled: "SettledCells"
    block_cover: dict[int, int] = field(default_factory=dict)  # (block, polygon) key -> how the block lies against it

    @classmethod
    def from_scene(cls, scene: PDMScene, cell: float = GRID_CELL_M, max_cells: int = MAX_GRID_CELLS) -> "DrivableMap":
        """The scene's map with a grid of ``cell`` metres (coarser past ``max_cells`` per axis); the grid changes
        only how fast points are located, never their answers."""
        polygons = ragged_polygons(scene.polygon_xy, scene.polygon_offsets)
        keep = np.isin(scene.polygon_kind, SCORED_KINDS)
        if len(polygons) != len(keep):
            raise ValueError(
                f"scene {scene.key!r}: polygon_offsets describe {len(polygons)} polygons with points, polygon_kind "
                f"has {len(keep)}; every polygon needs at least one point (rebuild scoring.npz)"
            )
        polygons = polygons[keep]
        shapely.prepare(polygons)
        ids, kinds = np.asarray(scene.polygon_id, np.int64)[keep], np.asarray(scene.polygon_kind)[keep]
        bounds = shapely.bounds(polygons).reshape(-1, 4)
        grid = BoundsGrid.build(bounds, cell, max_cells)
        cover = np.full(len(grid.members), UNKNOWN, np.int8)
        settled = SettledCells.empty(grid, IS_LANE[kinds])
        return cls(polygons, ids, kinds, grid, np.ascontiguousarray(bounds.T), cover, settled)

    def locate(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(index, polygon)`` for every point ``(x, y)`` (each ``(B, P)``) strictly inside a polygon, ``index`` the
        point's flat position ``box * P + point`` in increasing order."""
        x, y = x.reshape(-1), y.reshape(-1)
        index, entry = self.grid.candidates(x, y)
        cover = np.take(self.cover, entry)
        unknown = cover == UNKNOWN
        if unknown.any():
            self._classify(np.unique(entry[unknown]))
            cover = self.cover[entry]
        held = cover == INSIDE
        crossed = np.flatnonzero(cover == CROSSED)
        crossed_points = index[crossed]
        x, y = x[crossed_points], y[crossed_points]
        polygon = self.grid.members[entry[crossed]]
        xmin, ymin, xmax, ymax = np.take(self.bounds, polygon, axis=1)  # np.take: far faster than fancy indexing
        near = np.flatnonzero((x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax))
        held[crossed[near[shapely.contains_xy(self.polygons[polygon[near]], x[near], y[near])]]] = True
        held = np.flatnonzero(held)  # one pass over the mask for both gathers
        return index[held], self.grid.members[entry[held]]

    def _classify(self, entries: np.ndarray) -> None:
        """Set ``cover`` of grid ``entries``: the cell's grown square inside its polygon, clear of it or crossed.
        The block of :data:`BLOCK_CELLS` x :data:`BLOCK_CELLS` cells holding the cell is classified first (once per
        block and polygon): a cell of a block inside or clear of the polygon is so too (its grown square lies within
        the block's), and only cells of crossed blocks get a GEOS call each."""
        polygon = self.grid.members[entries]
        keys, first, of_entry = np.unique(
            self.grid.blocks(entries, BLOCK_CELLS) * len(self.polygons) + polygon,
            return_index=True,
            return_inverse=True,
        )
        known = self.block_cover
        new = [i for i, key in enumerate(keys.tolist()) if key not in known]
        if new:
            states = self._cover_of(entries[first[new]], BLOCK_CELLS)
            known.update(zip(keys[new].tolist(), states.tolist(), strict=True))
        by_block = np.array([known[key] for key in keys.tolist()], np.int8)[of_entry]
        self.cover[entries] = by_block
        crossed = entries[by_block == CROSSED]
        self.cover[crossed] = self._cover_of(crossed, 1)

    def _cover_of(self, entries: np.ndarray, block: int) -> np.ndarray:
        """How the grown square of each entry's cell (or of its block of ``block`` cells) lies against its polygon."""
        squares = self.grid.squares(entries, CELL_MARGIN_M, block)
        polygons = self.polygons[self.grid.members[entries]]
        crossed = np.where(shapely.intersects(polygons, squares), CROSSED, CLEAR)
        return np.where(shapely.contains_properly(polygons, squares), INSIDE, crossed).astype(np.int8)

    def layers(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What the ego-area flags need of points ``(x, y)`` (each ``(B,)``): per point, inside a drivable polygon
        (ROADBLOCK, INTERSECTION, CARPARK_AREA), inside an INTERSECTION, and the lane polygons holding it, slot by slot
        ``(W, B)`` (-1 pads)."""
        cells = self.grid.cells_of(x, y)
        settled = self.settled
        state = settled.state[cells]
        if (state == CELL_UNKNOWN).any():
            self._settle(np.unique(cells[state == CELL_UNKNOWN]))
            state = settled.state[cells]
        # as many lane slots as these points' cells can fill (a crossed cell: as many as it lists lanes)
        width = max(1, int(settled.lane_count[cells].max(initial=0)))
        drivable, intersection, lanes = _settled_answers(
            cells, settled.drivable, settled.intersection, settled.lanes, width
        )
        crossed = np.flatnonzero(state == CELL_CROSSED)  # their cells' answers are empty: set them here
        index, polygon = self.locate(x[crossed], y[crossed])
        point, kind = crossed[index], self.kinds[polygon]
        drivable[point[IS_DRIVABLE[kind]]] = True
        intersection[point[kind == MapKind.INTERSECTION]] = True
        lane = IS_LANE[kind]
        np.put(lanes, _ranks(index[lane]) * len(cells) + point[lane], polygon[lane])  # lanes[rank, point]
        return drivable, intersection, lanes

    def _settle(self, cells: np.ndarray) -> None:
        """Classify every member of ``cells`` and record, for those no polygon edge crosses, the answer every point
        in them gets: the polygons whose interior holds the cell's grown square."""
        position, entry = self.grid.expand(cells)
        unknown = self.cover[entry] == UNKNOWN
        if unknown.any():
            self._classify(entry[unknown])
        cover = self.cover[entry]
        crossed = np.zeros(len(cells), bool)
        crossed[position[cover == CROSSED]] = True
        inside = (cover == INSIDE) & ~crossed[position]
        position, polygon = position[inside], self.grid.members[entry[inside]]
        kind = self.kinds[polygon]
        settled = self.settled
        settled.drivable[cells[position[IS_DRIVABLE[kind]]]] = True
        settled.intersection[cells[position[kind == MapKind.INTERSECTION]]] = True
        lane = IS_LANE[kind]
        rank = _ranks(position[lane])
        settled.lanes[rank, cells[position[lane]]] = polygon[lane]
        settled.lane_count[cells[~crossed]] = 0
        np.maximum.at(settled.lane_count, cells[position[lane]], rank + 1)
        settled.state[cells] = np.where(crossed, CELL_CROSSED, CELL_SETTLED)


#: How a grid cell stands (``SettledCells.state``): not yet classified, every point of it answered by the cell,
#: or crossed by some polygon's edge (its points are located one by one).
CELL_UNKNOWN, CELL_SETTLED, CELL_CROSSED = -1, 0, 1


@njit(cache=True)
def _cells_of(
    x: np.ndarray, y: np.ndarray, origin_x: float, origin_y: float, cell: float, rows: int, columns: int
) -> np.ndarray:  # fmt: skip
    """:meth:`BoundsGrid.cells_of` in one pass: floor((coordinate - origin) / cell) per axis."""
    cells = np.empty(len(x), np.int64)
    for i in range(len(x)):
        row, column = np.floor((x[i] - origin_x) / cell), np.floor((y[i] - origin_y) / cell)
        if 0.0 <= row < rows and 0.0 <= column < columns:  # NaN fails both
            cells[i] = int(row) * columns + int(column)
        else:
            cells[i] = rows * columns
    return cells


@njit(cache=True)
def _settled_answers(
    cells: np.ndarray, drivable: np.ndarray, intersection: np.ndarray, lanes: np.ndarray, width: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Each point's cell's answers (:class:`SettledCells`): drivable, intersection and ``width`` lane slots."""
    count = len(cells)
    point_drivable, point_intersection = np.empty(count, np.bool_), np.empty(count, np.bool_)
    point_lanes = np.empty((width, count), lanes.dtype)
    for i in range(count):
        cell = cells[i]
        point_drivable[i], point_intersection[i] = drivable[cell], intersection[cell]
        for slot in range(width):
            point_lanes[slot, i] = lanes[slot, cell]
    return point_drivable, point_intersection, point_lanes


@dataclass
class SettledCells:
    """Per grid cell (and the empty cell off the grid), once its members are classified: its state and, where no
    polygon edge crosses it, what holds every point of it (a drivable polygon, an intersection, which lanes)."""

    state: np.ndarray  # (cells,) int8
    drivable: np.ndarray  # (cells,) bool
    intersection: np.ndarray  # (cells,) bool
    lanes: np.ndarray  # (W, cells) lane polygons holding the cell, slot by slot, -1 pads; W: the most any cell lists
    lane_count: np.ndarray  # (cells,) slots of ``lanes`` in use; a crossed (or unknown) cell: the lanes it lists

    @classmethod
    def empty(cls, grid: BoundsGrid, is_lane: np.ndarray) -> "SettledCells":
        count = len(grid.starts) - 1
        listed = np.bincount(grid.member_cells[is_lane[grid.members]], minlength=count)
        state = np.full(count, CELL_UNKNOWN, np.int8)
        state[-1] = CELL_SETTLED  # off the grid: no polygon
        lanes = np.full((max(1, int(listed.max(initial=0))), count), -1, np.int32)
        return cls(state, np.zeros(count, bool), np.zeros(count, bool), lanes, listed)


def _ranks(group: np.ndarray) -> np.ndarray:
    """Each element's rank within its run of equal values in ``group`` (runs consecutive)."""
    position = np.arange(len(group))
    new_run = np.ones(len(group), bool)
    new_run[1:] = group[1:] != group[:-1]
    return position - np.maximum.accumulate(np.where(new_run, position, 0))


@dataclass
class EgoAreas:
    """``(N, T)`` flags of NAVSIM's ``EgoAreaIndex`` and INTERSECTION membership of the rear axle and the centre."""

    multiple_lanes: np.ndarray
    non_drivable_area: np.ndarray
    oncoming_traffic: np.ndarray
    rear_axle_in_intersection: np.ndarray
    center_in_intersection: np.ndarray


def ego_areas(
    drivable_map: DrivableMap, coords: np.ndarray, rear_axles: np.ndarray, route_lane_ids: np.ndarray
) -> EgoAreas:
    """The ego-area flags of ego boxes ``(N, T, 5, 2)`` (4 corners + centre) with rear axles ``(N, T, 2)``."""
    n_rows, n_steps = coords.shape[:2]
    num_boxes = n_rows * n_steps
    # per box its corners, centre and rear axle, x and y apart
    x, y = (
        np.concatenate([coords[..., axis].reshape(num_boxes, -1), rear_axles[..., axis].reshape(num_boxes, 1)], axis=1)
        for axis in range(2)
    )
    per_box = x.shape[1]
    drivable, in_intersection, lanes = drivable_map.layers(x.reshape(-1), y.reshape(-1))
    drivable = drivable.reshape(num_boxes, per_box)
    corners_drivable = reduce(np.logical_and, [drivable[:, corner] for corner in range(NUM_CORNERS)])
    lanes = lanes.reshape(-1, num_boxes, per_box)  # (W, boxes, points)
    # a lane index -1 (a pad) reads the appended False
    on_route_lane = np.append(np.isin(drivable_map.ids, route_lane_ids) & IS_LANE[drivable_map.kinds], False)
    on_route = on_route_lane[lanes[:, :, Corner.CENTER]].any(axis=0)
    in_intersection = in_intersection.reshape(num_boxes, per_box)

    def grid(flags: np.ndarray) -> np.ndarray:
        return flags.reshape(n_rows, n_steps)

    return EgoAreas(
        grid(multiple_lanes(lanes[:, :, :NUM_CORNERS].transpose(2, 0, 1))),
        grid(~corners_drivable),
        grid(~on_route),
        grid(in_intersection[:, -1]),
        grid(in_intersection[:, Corner.CENTER]),
    )


def multiple_lanes(by_corner: np.ndarray) -> np.ndarray:
    """NAVSIM's MULTIPLE_LANES from the corners' lane polygons ``(4, W, boxes)`` (-1 pads): more than one distinct
    polygon among the corners, and none holding all four."""
    by_corner = np.ascontiguousarray(by_corner)  # each slot a contiguous row
    num_boxes = by_corner.shape[-1]
    slots = by_corner.reshape(-1, num_boxes)
    # more than one distinct lane: some lane other than the largest one present (pads are -1, below every lane)
    largest = reduce(np.maximum, slots)
    several = np.zeros(num_boxes, bool)
    for lane in slots:
        several |= (lane >= 0) & (lane < largest)
    in_all = np.zeros(num_boxes, bool)
    for lane in by_corner[0]:  # each lane of corner 0: also held by the three others?
        held_by_all = lane >= 0
        for other in by_corner[1:]:
            held_by_all &= np.logical_or.reduce([slot == lane for slot in other])
        in_all |= held_by_all
    return several & ~in_all
