"""Schema v1 sample -> model input tensors (the :class:`lead_s2r.models.inputs.Batch` contract), per source.

Everything here is a pure function of one decoded sample and the model configuration: resampling of the
native-rate future to the model's grid, cameras stitched into the input image, LiDAR rasterised onto the BEV grid,
CenterNet box targets, BEV/perspective labels moved onto the model's grids. A label a sample does not have is left
out, and the loss masks it.

Cameras are never squashed: a CARLA 3:1 mosaic stretched into LTFv6's 7:1 input would show every object 2.4x too
wide, a gap between sources that no amount of training closes. Each tile is first cut by its calibration to the
vertical field of view the model asks for (``vertical_fov_deg``, rows around the principal point; padded where the
camera sees less), the tiles are stitched at one height, and the strip is scaled uniformly into ``image_size``,
centred and padded (letterboxed) when its aspect differs by more than :data:`ASPECT_TOLERANCE`, with a warning. The
layout depends only on the configuration and the source's rig, so it is computed once per rig
(:func:`camera_layout`) and then applied to the image and its perspective labels alike (:func:`render`).
"""

import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Any

import cv2
import numpy as np
import torch

from lead_s2r.geometry import raster_lookup, resample, rotate
from lead_s2r.models.config import BEVGrid, TFv6Config
from lead_s2r.schema import BoxClass, command4

#: Radar points kept per sample (LEAD: 4 sensors x 75).
MAX_RADAR_POINTS = 300
#: Boxes kept per sample for the CenterNet regression targets.
MAX_BOXES = 64
#: Radar detection targets per sample (LEAD: up to 20 objects with at least one radar hit).
MAX_RADAR_TARGETS = 20
#: A radar point counts as a hit on a box up to this far outside its footprint, metres.
RADAR_HIT_MARGIN_M = 0.5
#: LiDAR histogram saturation (LEAD's ``rasterize_lidar``: clip at 5 hits per cell, scale to [0, 1]).
LIDAR_HITS_MAX = 5.0
#: Route checkpoints start this far ahead, then come every metre (LEAD's ``smooth_path``).
ROUTE_START_M = 2.5
CENTERNET_STRIDE = 4
#: A camera strip within this relative aspect difference of ``image_size`` is stretched to fill it (a distortion
#: below what anyone sees); beyond it, it is letterboxed.
ASPECT_TOLERANCE = 0.02


@dataclass(frozen=True)
class Tile:
    """One camera tile's geometry in a decoded camera image: columns ``[x0, x1)``; ``fy`` and ``cy`` (pixels) from
    its calibration, None where the sample has none."""

    x0: int
    x1: int
    fy: float | None = None
    cy: float | None = None


@dataclass(frozen=True)
class Band:
    """The pixels of one decoded image that become one tile of the input strip: columns ``[x0, x1)``, rows
    ``[top, bottom)``. Rows outside the image are padding (the requested field of view exceeds the camera's)."""

    x0: int
    x1: int
    top: int
    bottom: int


@dataclass(frozen=True)
class CameraLayout:
    """Where every camera's pixels go in the model's input image.

    Attributes:
        sizes: the decoded (height, width) of each camera field the bands refer to.
        bands: per camera field, its bands left to right.
        strip: (height, width) of the stitched strip, every band scaled to the first one's height.
        image_size: the model's (H, W).
        box: (y0, x0, height, width) that the scaled strip fills in the model image; the rest is padding.
    """

    sizes: tuple[tuple[int, int], ...]
    bands: tuple[tuple[Band, ...], ...]
    strip: tuple[int, int]
    image_size: tuple[int, int]
    box: tuple[int, int, int, int]

    @property
    def letterboxed(self) -> bool:
        return self.box[2:] != self.image_size


def camera_tiles(meta: dict[str, Any], camera: str, shape: tuple[int, int]) -> tuple[Tile, ...]:
    """The tiles of camera field ``camera`` from ``meta.cameras``, scaled to the decoded image ``shape``.

    A mosaic lists one calibration per tile (``tile`` = [x0, width]); a camera without calibration is one tile
    without intrinsics.
    """
    height, width = shape
    entries = [c for c in meta.get("cameras", []) if c.get("id") == camera]
    if not entries:
        return (Tile(0, width),)
    entries.sort(key=lambda c: c["tile"][0] if "tile" in c else 0)
    stored_width = max((c["tile"][0] + c["tile"][1]) if "tile" in c else c["width"] for c in entries)
    sx, sy = width / stored_width, height / entries[0]["height"]
    tiles = []
    for c in entries:
        x0, w = c["tile"] if "tile" in c else (0, c["width"])
        tiles.append(Tile(round(x0 * sx), round((x0 + w) * sx), float(c["K"][1][1]) * sy, float(c["K"][1][2]) * sy))
    return tuple(tiles)


def tile_bands(height: int, tiles: Sequence[Tile], vertical_fov_deg: float | None) -> tuple[Band, ...]:
    """Rows of each tile covering ``vertical_fov_deg`` around its principal point (all rows when None);
    neighbouring tiles with the same rows merge into one band."""
    bands: list[Band] = []
    for tile in tiles:
        if vertical_fov_deg is None:
            top, bottom = 0, height
        elif tile.fy is None or tile.cy is None:
            raise ValueError("vertical_fov_deg needs each camera's calibration (meta.cameras K), and one has none")
        else:
            half = tile.fy * math.tan(math.radians(vertical_fov_deg) / 2)
            top, bottom = round(tile.cy - half), round(tile.cy + half)
        last = bands[-1] if bands else None
        if last is not None and last.x1 == tile.x0 and (last.top, last.bottom) == (top, bottom):
            bands[-1] = Band(last.x0, tile.x1, top, bottom)
        else:
            bands.append(Band(tile.x0, tile.x1, top, bottom))
    return tuple(bands)


@lru_cache(maxsize=256)
def camera_layout(
    cameras: tuple[tuple[tuple[int, int], tuple[Tile, ...]], ...],
    image_size: tuple[int, int],
    vertical_fov_deg: float | None,
) -> CameraLayout:
    """The layout of camera fields given as ((height, width), tiles) each, in the model's ``image_size``."""
    if vertical_fov_deg is not None and not 0.0 < vertical_fov_deg < 180.0:
        raise ValueError(f"vertical_fov_deg must be in (0, 180), got {vertical_fov_deg}")
    bands = tuple(tile_bands(shape[0], tiles, vertical_fov_deg) for shape, tiles in cameras)
    flat = [band for per_camera in bands for band in per_camera]
    strip_h = flat[0].bottom - flat[0].top
    strip_w = sum(round((b.x1 - b.x0) * strip_h / (b.bottom - b.top)) for b in flat)
    h, w = image_size
    if abs(strip_w * h / (strip_h * w) - 1.0) <= ASPECT_TOLERANCE:
        box = (0, 0, h, w)
    else:
        scale = min(h / strip_h, w / strip_w)
        box_h, box_w = round(strip_h * scale), round(strip_w * scale)
        box = ((h - box_h) // 2, (w - box_w) // 2, box_h, box_w)
    sizes = tuple(shape for shape, _ in cameras)
    return CameraLayout(sizes, bands, (strip_h, strip_w), (h, w), box)


def _cut(image: np.ndarray, band: Band, scale: tuple[float, float], fill: float) -> np.ndarray:
    """One band of ``image`` (which may be a label at another resolution than the layout's: ``scale``)."""
    sy, sx = scale
    top, bottom = round(band.top * sy), round(band.bottom * sy)
    piece = image[max(top, 0) : min(bottom, image.shape[0]), round(band.x0 * sx) : round(band.x1 * sx)]
    if top >= 0 and bottom <= image.shape[0]:
        return piece
    pad = [(max(-top, 0), max(bottom - image.shape[0], 0)), (0, 0)] + [(0, 0)] * (image.ndim - 2)
    return np.pad(piece, pad, constant_values=fill)


def render(layout: CameraLayout, images: Sequence[np.ndarray], interpolation: int, fill: float) -> np.ndarray:
    """Apply ``layout`` to one image per camera field (RGB, or a label at any resolution): (H, W[, C])."""
    pieces = []
    for size, bands, image in zip(layout.sizes, layout.bands, images, strict=True):
        scale = (image.shape[0] / size[0], image.shape[1] / size[1])
        pieces.extend(_cut(image, band, scale, fill) for band in bands)
    height = pieces[0].shape[0]
    pieces = [p if p.shape[0] == height else _resize_height(p, height, interpolation) for p in pieces]
    y0, x0, box_h, box_w = layout.box
    strip = cv2.resize(np.hstack(pieces) if len(pieces) > 1 else pieces[0], (box_w, box_h), interpolation=interpolation)
    if not layout.letterboxed:
        return strip
    canvas = np.full(layout.image_size + strip.shape[2:], fill, strip.dtype)
    canvas[y0 : y0 + box_h, x0 : x0 + box_w] = strip
    return canvas


@dataclass
class SourceTransform:
    """Turns samples of one source into tensors for ``config``.

    Args:
        source: the source name the model knows (its trajectory grid and label space), e.g. "carla".
        config: the model configuration (image size, BEV grid, trajectory grids, head sizes).
        cameras: camera fields stitched left to right into the input image (without the ``cam_`` prefix).
    """

    source: str
    config: TFv6Config
    cameras: list[str] = field(default_factory=lambda: ["carla_mosaic"])
    _reported: set[CameraLayout] = field(default_factory=set, init=False, repr=False)  # letterboxed layouts warned of

    @property
    def fields(self) -> list[str]:
        """The sample fields this transform reads, so loaders decode nothing else (``meta`` always comes)."""
        fields = ["past", "future", "target_points", "route", "lidar", "radar", "boxes", "bev_semantic"]
        fields += [f"cam_{camera}" for camera in self.cameras]
        if len(self.cameras) == 1:
            fields += [f"depth_{self.cameras[0]}", f"semantic_{self.cameras[0]}"]
        return fields

    def __call__(self, sample: dict[str, Any]) -> dict[str, Any]:
        meta = sample["meta"]
        ego = meta["ego"]
        out: dict[str, Any] = {
            "__key__": sample["__key__"],
            "__dataset__": meta["dataset"],
            "speed": torch.tensor(float(ego["speed"])),
            "acceleration": torch.tensor(ego["acceleration"], dtype=torch.float32),
            "command": torch.tensor(int(command4(ego["command"])), dtype=torch.int64),
        }
        if self.cameras:  # a model without cameras (the ego-status MLP) decodes no image
            out["rgb"], layout = self.image(sample)
        out.update(self.target_points(sample))
        if self.config.bev_input == "raster":
            out["lidar_bev"] = torch.from_numpy(rasterize_lidar(sample.get("lidar"), self.config.bev))[None]
        if self.config.use_radar:
            out.update(pad_points("radar", sample.get("radar"), MAX_RADAR_POINTS, 5))
            if "radar" in sample and "boxes" in sample and self.source in self.config.radar_sources:
                out.update(radar_targets(sample["radar"], sample["boxes"]))
        if "future" in sample:
            out.update(self.trajectory(sample["future"]))
        if "route" in sample:
            out.update(route_checkpoints(sample["route"], self.config.num_route_points))
        target_speed = meta["extras"].get(meta["dataset"], {}).get("target_speed")
        if target_speed is not None:
            out["target_speed"] = torch.tensor(float(target_speed))
            out["target_speed_valid"] = torch.tensor(True)
        space = self.config.space(self.source)
        if "bev_semantic" in sample and space in self.config.bev_semantic_classes:
            out["bev_semantic"] = torch.from_numpy(bev_labels(sample["bev_semantic"], meta["bev"], self.config.bev))
        if "boxes" in sample and space in self.config.box_classes:
            out.update(centernet_targets(sample["boxes"], self.config.bev, self.config.box_classes[space]))
        if len(self.cameras) == 1:
            out.update(self.perspective_labels(sample, space, layout))
        return out

    def image(self, sample: dict[str, Any]) -> tuple[torch.Tensor, CameraLayout]:
        """Cameras decoded and laid out in ``config.image_size`` (see the module docstring): uint8 (3, H, W) RGB,
        and the layout, which perspective labels follow."""
        images = []
        for camera in self.cameras:
            data = sample.get(f"cam_{camera}")
            if data is None:
                raise KeyError(f"sample {sample['__key__']!r} has no camera {camera!r} (field cam_{camera})")
            images.append(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR))
        layout = self.layout(sample["meta"], [image.shape[:2] for image in images])
        image = render(layout, images, cv2.INTER_AREA, 0)
        return torch.from_numpy(np.ascontiguousarray(image[:, :, ::-1].transpose(2, 0, 1))), layout

    def layout(self, meta: dict[str, Any], shapes: Sequence[tuple[int, int]]) -> CameraLayout:
        """The (cached) layout of this sample's rig; warns when it does not fill the model's image."""
        fov = self.config.vertical_fov_deg
        cameras = []
        for camera, shape in zip(self.cameras, shapes, strict=True):
            tiles = camera_tiles(meta, camera, shape)
            if fov is None:  # intrinsics do not matter: one layout for every calibration of the rig
                tiles = tuple(Tile(t.x0, t.x1) for t in tiles)
            cameras.append((tuple(shape), tiles))
        try:
            layout = camera_layout(tuple(cameras), tuple(self.config.image_size), fov)
        except ValueError as err:
            raise ValueError(f"source {self.source!r}, cameras {self.cameras}: {err}") from None
        if layout.letterboxed and layout not in self._reported:
            self._reported.add(layout)
            self._letterboxed(layout)
        return layout

    def _letterboxed(self, layout: CameraLayout) -> None:
        (strip_h, strip_w), (h, w) = layout.strip, layout.image_size
        y0, x0, box_h, box_w = layout.box
        c = self.config
        if c.use_tiles is not None or c.fov_fraction < 1.0:
            raise ValueError(
                f"source {self.source!r}: the camera ablations (camera_tiles, use_tiles, fov_fraction) cut equal "
                f"tiles from a mosaic that fills image_size, but this source's {strip_w}x{strip_h} strip is "
                f"letterboxed into {w}x{h}; set image_size to the strip's aspect"
            )
        warnings.warn(
            f"source {self.source!r}: cameras {self.cameras} make a {strip_w}x{strip_h} strip (aspect "
            f"{strip_w / strip_h:.2f}) but the model's image is {w}x{h} (aspect {w / h:.2f}); letterboxed into "
            f"{box_w}x{box_h} at x={x0}, y={y0} instead of squashed. Match image_size (or vertical_fov_deg) to "
            "this rig to use every input pixel",
            stacklevel=2,
        )

    def target_points(self, sample: dict[str, Any]) -> dict[str, torch.Tensor]:
        points = sample.get("target_points")
        if points is None:
            return {"target_points": torch.zeros(3, 2), "target_points_valid": torch.zeros(3, dtype=torch.bool)}
        valid = np.isfinite(points).all(axis=1)
        return {
            "target_points": torch.from_numpy(np.where(valid[:, None], points, 0).astype(np.float32)),
            "target_points_valid": torch.from_numpy(valid),
        }

    def trajectory(self, future: np.ndarray) -> dict[str, torch.Tensor]:
        """Waypoints (and headings, where the source has them) on the source's output grid, masked beyond the
        recorded horizon."""
        times = np.asarray(self.config.trajectory_grids[self.source].times)
        knots = np.vstack([np.zeros((1, 4), np.float32), future])  # the ego sits at the origin at t = 0
        poses, valid = resample(knots[:, 0], knots[:, 1:], times, angle_columns=(2,))
        out = {
            "waypoints": torch.from_numpy(np.nan_to_num(poses[:, :2]).astype(np.float32)),
            "waypoints_valid": torch.from_numpy(valid),
        }
        heading_valid = valid & np.isfinite(poses[:, 2])
        if heading_valid.any():  # a source without headings (WOD-E2E) must not dilute the heading loss of others
            out["headings"] = torch.from_numpy(np.nan_to_num(poses[:, 2]).astype(np.float32))
            out["headings_valid"] = torch.from_numpy(heading_valid)
        return out

    def perspective_labels(self, sample: dict[str, Any], space: str, layout: CameraLayout) -> dict[str, torch.Tensor]:
        """Depth (metres, 0 = no label) and semantic ids (-1 = ignore) of the single input camera, laid out on the
        input image's pixel grid exactly as the image is."""
        camera = self.cameras[0]
        out = {}
        depth = sample.get(f"depth_{camera}")
        if depth is not None and space in self.config.depth_sources:
            encoding = sample["meta"].get("depth", {})
            metres = depth.astype(np.float32) / 255.0 * float(encoding.get("max_m", self.config.max_depth))
            out["depth"] = torch.from_numpy(render(layout, [metres], cv2.INTER_LINEAR, 0.0))
        semantic = sample.get(f"semantic_{camera}")
        if semantic is not None and space in self.config.semantic_classes:
            ids = render(layout, [semantic.astype(np.int16)], cv2.INTER_NEAREST, IGNORE_VALUE["semantic"])
            out["semantic"] = torch.from_numpy(ids.astype(np.int64))
        return out


def _resize_height(image: np.ndarray, height: int, interpolation: int) -> np.ndarray:
    width = max(1, round(image.shape[1] * height / image.shape[0]))
    return cv2.resize(image, (width, height), interpolation=interpolation)


def bev_cell_centres(grid: BEVGrid, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Ego x (rows) and y (columns) of the cell centres of ``grid`` at ``stride``."""
    h, w = grid.shape
    cell = stride / grid.pixels_per_meter
    xs = grid.x_min + (np.arange(h // stride) + 0.5) * cell
    ys = grid.y_min + (np.arange(w // stride) + 0.5) * cell
    return xs, ys


def rasterize_lidar(points: np.ndarray | None, grid: BEVGrid) -> np.ndarray:
    """Point histogram on ``grid`` (H along +x, W along +y), saturated at 5 hits: float32 (H, W) in [0, 1]."""
    h, w = grid.shape
    if points is None or not len(points):
        return np.zeros((h, w), np.float32)
    rows = np.floor((points[:, 0] - grid.x_min) * grid.pixels_per_meter).astype(np.int64)
    cols = np.floor((points[:, 1] - grid.y_min) * grid.pixels_per_meter).astype(np.int64)
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    counts = np.bincount(rows[inside] * w + cols[inside], minlength=h * w).reshape(h, w)
    return (np.minimum(counts, LIDAR_HITS_MAX) / LIDAR_HITS_MAX).astype(np.float32)


def pad_points(name: str, points: np.ndarray | None, size: int, columns: int) -> dict[str, torch.Tensor]:
    """First ``size`` rows of ``points`` zero-padded to a fixed length, with a validity mask."""
    padded = np.zeros((size, columns), np.float32)
    valid = np.zeros(size, bool)
    if points is not None:
        n = min(len(points), size)
        padded[:n] = points[:n, :columns]
        valid[:n] = True
    return {name: torch.from_numpy(padded), f"{name}_valid": torch.from_numpy(valid)}


def radar_targets(radar: np.ndarray, boxes: np.ndarray) -> dict[str, torch.Tensor]:
    """Radar detection targets: [x, y, speed] of the boxes radar points fall on, fastest first (as LEAD sorts).

    A point hits a box when it lies inside the box's footprint grown by :data:`RADAR_HIT_MARGIN_M`.
    """
    targets = np.zeros((MAX_RADAR_TARGETS, 3), np.float32)
    valid = np.zeros(MAX_RADAR_TARGETS, bool)
    if len(radar) and len(boxes):
        local = rotate(radar[None, :, :2] - boxes[:, None, :2], -boxes[:, None, 6])  # (N boxes, P points, 2)
        half = boxes[:, None, 3:5] / 2 + RADAR_HIT_MARGIN_M
        hit = (np.abs(local) <= half).all(axis=-1).any(axis=1)
        speed = np.hypot(boxes[:, 7], boxes[:, 8])
        chosen = np.flatnonzero(hit)[np.argsort(-speed[hit], kind="stable")][:MAX_RADAR_TARGETS]
        targets[: len(chosen)] = np.stack([boxes[chosen, 0], boxes[chosen, 1], speed[chosen]], axis=1)
        valid[: len(chosen)] = True
    return {"radar_targets": torch.from_numpy(targets), "radar_targets_valid": torch.from_numpy(valid)}


def route_checkpoints(route: np.ndarray, count: int) -> dict[str, torch.Tensor]:
    """Points along the route at 2.5 m, 3.5 m, ... of arc length from the ego (the origin); masked past its end."""
    route = np.vstack([np.zeros((1, 2)), np.asarray(route, np.float64)])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=1))])
    keep = np.concatenate([[True], np.diff(arc) > 1e-6])  # repeated points would stall the interpolation
    targets = ROUTE_START_M + np.arange(count, dtype=np.float64)
    if keep.sum() < 2:
        points, valid = np.zeros((count, 2)), np.zeros(count, bool)
    else:
        points, valid = resample(arc[keep], route[keep], targets)
    return {
        "route": torch.from_numpy(np.nan_to_num(points).astype(np.float32)),
        "route_valid": torch.from_numpy(valid),
    }


def bev_labels(labels: np.ndarray, spec: dict[str, Any], grid: BEVGrid) -> np.ndarray:
    """Class ids of a stored BEV raster (``meta.bev`` spec) at ``grid``'s cell centres; -1 outside the raster."""
    xs, ys = bev_cell_centres(grid)
    x, y = np.meshgrid(xs, ys, indexing="ij")
    return raster_lookup(labels, spec["pixel_to_ego"], x, y)


def centernet_targets(boxes: np.ndarray, grid: BEVGrid, num_classes: int) -> dict[str, torch.Tensor]:
    """CenterNet targets on ``grid`` at stride 4: Gaussian heatmaps per class and per-box regression targets.

    With a single class only vehicles are kept (NAVSIM's agent head); otherwise the class is the unified
    :class:`~lead_s2r.schema.BoxClass` id.
    """
    xs, ys = bev_cell_centres(grid, CENTERNET_STRIDE)
    h, w = len(xs), len(ys)
    cell = CENTERNET_STRIDE / grid.pixels_per_meter
    heatmap = np.zeros((num_classes, h, w), np.float32)
    regression = {
        "box_index": np.zeros(MAX_BOXES, np.int64),
        "box_valid": np.zeros(MAX_BOXES, bool),
        "box_offset": np.zeros((MAX_BOXES, 2), np.float32),
        "box_size": np.zeros((MAX_BOXES, 2), np.float32),
        "box_yaw": np.zeros(MAX_BOXES, np.float32),
        "box_velocity": np.zeros(MAX_BOXES, np.float32),
    }
    slot = 0
    rows_grid, cols_grid = np.arange(h)[:, None], np.arange(w)[None, :]
    for box in boxes:
        label = int(box[9])
        if num_classes == 1:
            if label != BoxClass.VEHICLE:
                continue
            label = 0
        elif label >= num_classes:
            continue
        row_f, col_f = (box[0] - grid.x_min) / cell, (box[1] - grid.y_min) / cell
        row, col = math.floor(row_f), math.floor(col_f)
        if not (0 <= row < h and 0 <= col < w) or slot == MAX_BOXES:
            continue
        sigma = max(0.5, min(box[3], box[4]) / cell / 6.0)
        gaussian = np.exp(-((rows_grid - row) ** 2 + (cols_grid - col) ** 2) / (2 * sigma**2)).astype(np.float32)
        np.maximum(heatmap[label], gaussian, out=heatmap[label])
        regression["box_index"][slot] = row * w + col
        regression["box_valid"][slot] = True
        regression["box_offset"][slot] = (row_f - row, col_f - col)
        regression["box_size"][slot] = (box[3], box[4])
        regression["box_yaw"][slot] = box[6]
        regression["box_velocity"][slot] = math.hypot(box[7], box[8])
        slot += 1
    return {"box_heatmap": torch.from_numpy(heatmap), **{k: torch.from_numpy(v) for k, v in regression.items()}}


#: Fill value of a label a sample lacks: the loss ignores it (masks are False, depth 0 means "no label").
IGNORE_VALUE = {"bev_semantic": -1, "semantic": -1, "box_heatmap": -1}


def collate(samples: list[dict[str, Any]]) -> dict[str, Any]:
    """Stack per-sample tensors into a batch; a label only some samples carry is filled where missing.

    Identity entries (``__key__``, ``__dataset__``) become lists. The filler is masked out by construction:
    validity masks are False, class maps -1, depth 0.
    """
    names = set().union(*samples)
    batch: dict[str, Any] = {name: [sample[name] for sample in samples] for name in names if name.startswith("__")}
    for key in sorted(name for name in names if not name.startswith("__")):
        template = next(sample[key] for sample in samples if key in sample)
        filler = torch.full_like(template, IGNORE_VALUE.get(key, 0))
        batch[key] = torch.stack([sample.get(key, filler) for sample in samples])
    return batch
