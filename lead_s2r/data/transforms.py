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

Speed (the loader runs this per sample on the CPU, beside the GPU): whatever depends only on the configuration and
a source's fixed spec is computed once per process and cached (camera layouts, the BEV label gather index, the
CenterNet Gaussian windows); a layout that maps an image onto itself is not resampled at all; JPEGs are decoded
straight to RGB, and at 1/2, 1/4 or 1/8 size (libjpeg's DCT scaling, OpenCV ``IMREAD_REDUCED_*``) where the
model's image is at least that much smaller than the camera's (:func:`jpeg_reduction`): the area-averaged result
then differs from the full decode by the rounding of JPEG's scaled IDCT only (measured on a smooth 1920x1080 q=90
image in tests/test_transform_speed.py: mean <= 0.34, max 2 levels of 255 at 1/2 to 1/8; the test allows 0.5 and 4).
Every other output is bit-identical to the straightforward definitions kept in that test, or (a perspective label
left at its stored size, see below) equal to float32 rounding once :func:`~lead_s2r.models.inputs.on_image_grid`
has put it on the image's grid.

Tensors are lean (the loader builds and stacks every byte on the CPU): the image uint8, the LiDAR raster uint8 hit
counts, class maps the stored uint8 ids (:data:`~lead_s2r.models.inputs.IGNORE_CLASS` where there is no label), and
a depth or semantic label smaller than the image under a plain resize (:attr:`CameraLayout.whole`) is not upsampled
here; the model and the losses scale, widen and resize them on the device. Images stay in the (H, W, 3) order decoders
write: a sample's ``rgb`` is a (3, H, W) view of it and a batch's a channels-last (B, 3, H, W) tensor, which is
also the memory format convolutions run fastest in on the GPU. A camera JPEG that is the model's image as stored
(one camera at ``image_size``) is decoded by libjpeg-turbo without OpenCV's conversions, or, with
``inputs_on_device``, not at all: the bytes go to the training device, and so do the LiDAR points, unrasterised
(:mod:`lead_s2r.data.device_inputs`).
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
from torch.utils.data import default_collate

from lead_s2r.data.device_inputs import LIDAR_POINTS, RGB_JPEG, decode_rgb, jpeg_tensor
from lead_s2r.geometry import raster_lookup, resample
from lead_s2r.models.config import BEVGrid, TFv6Config
from lead_s2r.models.inputs import IGNORE_CLASS, LIDAR_HITS_MAX, on_image_grid
from lead_s2r.schema import BoxClass, command4

#: Radar points kept per sample (LEAD: 4 sensors x 75).
MAX_RADAR_POINTS = 300
#: Boxes kept per sample for the CenterNet regression targets.
MAX_BOXES = 64
#: Radar detection targets per sample (LEAD: up to 20 objects with at least one radar hit).
MAX_RADAR_TARGETS = 20
#: A radar point counts as a hit on a box up to this far outside its footprint, metres.
RADAR_HIT_MARGIN_M = 0.5
#: Route checkpoints start this far ahead, then come every metre (LEAD's ``smooth_path``).
ROUTE_START_M = 2.5
CENTERNET_STRIDE = 4
#: A camera strip within this relative aspect difference of ``image_size`` is stretched to fill it (a distortion
#: below what anyone sees); beyond it, it is letterboxed.
ASPECT_TOLERANCE = 0.02
#: JPEG DCT-domain scalings OpenCV exposes (1/2, 1/4, 1/8), as (factor, imdecode flag without the colour bits).
_JPEG_REDUCTIONS = (
    (8, cv2.IMREAD_REDUCED_COLOR_8 & ~cv2.IMREAD_COLOR),
    (4, cv2.IMREAD_REDUCED_COLOR_4 & ~cv2.IMREAD_COLOR),
    (2, cv2.IMREAD_REDUCED_COLOR_2 & ~cv2.IMREAD_COLOR),
)


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

    @property
    def identity(self) -> bool:
        """One camera, one band that is the whole decoded image, at the model's size: nothing to resample."""
        return self.whole and self.sizes[0] == self.image_size

    @property
    def whole(self) -> bool:
        """One camera, one band that is the whole decoded image, filling the model's image: a plain resize."""
        if len(self.sizes) != 1 or len(self.bands[0]) != 1 or self.letterboxed:
            return False
        (h, w), band = self.sizes[0], self.bands[0][0]
        return (band.x0, band.x1, band.top, band.bottom) == (0, w, 0, h)


def camera_tiles(meta: dict[str, Any], camera: str, shape: tuple[int, int]) -> tuple[Tile, ...]:
    """The tiles of camera field ``camera`` from ``meta.cameras``, scaled to the decoded image ``shape``.

    A mosaic lists one calibration per tile (``tile`` = [x0, width]); a camera without calibration is one tile
    without intrinsics.
    """
    height, width = shape
    entries = _calibrations(meta, camera)
    if not entries:
        return (Tile(0, width),)
    stored_height, stored_width = _stored_size(entries)
    sx, sy = width / stored_width, height / stored_height
    tiles = []
    for c in entries:
        x0, w = c["tile"] if "tile" in c else (0, c["width"])
        tiles.append(Tile(round(x0 * sx), round((x0 + w) * sx), float(c["K"][1][1]) * sy, float(c["K"][1][2]) * sy))
    return tuple(tiles)


def _calibrations(meta: dict[str, Any], camera: str) -> list[dict[str, Any]]:
    """The ``meta.cameras`` entries of camera field ``camera``, left to right."""
    entries = [c for c in meta.get("cameras", []) if c.get("id") == camera]
    return sorted(entries, key=lambda c: c["tile"][0] if "tile" in c else 0)


def _stored_size(entries: list[dict[str, Any]]) -> tuple[int, int]:
    """(height, width) of the stored image the calibration ``entries`` describe."""
    width = max((c["tile"][0] + c["tile"][1]) if "tile" in c else c["width"] for c in entries)
    return int(entries[0]["height"]), int(width)


def jpeg_reduction(layout: CameraLayout) -> tuple[int, int]:
    """The largest JPEG scale-down (factor, imdecode flag) after which the strip still has at least as many rows and
    columns as the model's image gives it, so the area resize only shrinks; (1, 0) when none fits."""
    (strip_h, strip_w), (box_h, box_w) = layout.strip, layout.box[2:]
    for factor, flag in _JPEG_REDUCTIONS:
        if strip_h >= box_h * factor and strip_w >= box_w * factor:
            return factor, flag
    return 1, 0


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
    """Apply ``layout`` to one image per camera field (RGB, or a label at any resolution): (H, W[, C]).

    An image the layout maps onto itself comes back as it is (not copied)."""
    if layout.identity and images[0].shape[:2] == layout.image_size:
        return images[0]
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
        inputs_on_device: leave a camera JPEG that is the model's image as stored encoded (``rgb_jpeg``), for
            :func:`~lead_s2r.data.device_inputs.decode_images` on the training device (other rigs are decoded here), and
            the LiDAR points unrasterised (``lidar_points``), for :func:`~lead_s2r.data.device_inputs.rasterize_points`.
    """

    source: str
    config: TFv6Config
    cameras: list[str] = field(default_factory=lambda: ["carla_mosaic"])
    inputs_on_device: bool = False
    _reported: set[CameraLayout] = field(default_factory=set, init=False, repr=False)  # letterboxed layouts warned of

    @property
    def fields(self) -> list[str]:
        """The sample fields this transform reads, so loaders decode nothing else (``meta`` always comes)."""
        config, space = self.config, self.config.space(self.source)
        radar_targets = config.use_radar and self.source in config.radar_sources
        wanted = {
            "future": True,
            "target_points": True,
            "route": True,
            "lidar": config.bev_input == "raster",
            "radar": config.use_radar,
            "boxes": radar_targets or space in config.box_classes,
            "bev_semantic": space in config.bev_semantic_classes,
        }
        fields = [name for name, read in wanted.items() if read]
        fields += [f"cam_{camera}" for camera in self.cameras]
        if len(self.cameras) == 1:
            if space in config.depth_sources:
                fields.append(f"depth_{self.cameras[0]}")
            if space in config.semantic_classes:
                fields.append(f"semantic_{self.cameras[0]}")
        return fields

    def __call__(self, sample: dict[str, Any]) -> dict[str, Any]:
        meta = sample["meta"]
        ego = meta["ego"]
        out: dict[str, Any] = {
            "__key__": sample["__key__"],
            "__dataset__": meta["dataset"],
            "speed": torch.scalar_tensor(float(ego["speed"])),  # a third of torch.tensor's cost, same tensor
            "acceleration": torch.from_numpy(np.array(ego["acceleration"], np.float32)),
            "command": torch.scalar_tensor(int(command4(ego["command"])), dtype=torch.int64),
        }
        if self.cameras:  # a model without cameras (the ego-status MLP) decodes no image
            stored = self.stored_layout(meta)
            if self.inputs_on_device and stored is not None and stored.identity:
                out[RGB_JPEG], layout = jpeg_tensor(self._jpeg(sample, self.cameras[0])), stored
            else:
                out["rgb"], layout = self._laid_out(sample, stored)
        out.update(self.target_points(sample))
        if self.config.bev_input == "raster" and self.inputs_on_device:
            out[LIDAR_POINTS] = lidar_xy(sample.get("lidar"))
        elif self.config.bev_input == "raster":
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
            out["target_speed"] = torch.scalar_tensor(float(target_speed))
            out["target_speed_valid"] = torch.scalar_tensor(True, dtype=torch.bool)
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
        and the layout of the full-size images, which perspective labels follow.

        A JPEG that is the model's image as stored is decoded as it is; otherwise, where the calibration gives the
        stored sizes, JPEGs are decoded at the largest reduction (:func:`jpeg_reduction`) that still leaves the
        model's image to shrink into."""
        return self._laid_out(sample, self.stored_layout(sample["meta"]))

    def _laid_out(self, sample: dict[str, Any], layout: CameraLayout | None) -> tuple[torch.Tensor, CameraLayout]:
        """:meth:`image`, given the rig's layout at its stored sizes (None: no calibration)."""
        meta = sample["meta"]
        if layout is not None and layout.identity:
            try:
                image = decode_rgb([jpeg_tensor(self._jpeg(sample, self.cameras[0]))], "cpu")[0]
            except RuntimeError as err:
                raise ValueError(
                    f"sample {sample['__key__']!r}: field cam_{self.cameras[0]} is not a decodable JPEG ({err})"
                ) from None
            if tuple(image.shape[1:]) == layout.image_size:
                return image, layout
        factor, flag = (1, 0) if layout is None else jpeg_reduction(layout)
        images = [self._decode(sample, camera, cv2.IMREAD_COLOR_RGB | flag) for camera in self.cameras]
        decoded = self._rig_layout(meta, [image.shape[:2] for image in images])
        if factor > 1 and decoded.box != layout.box:  # rounding moved the letterbox: labels would not line up
            factor, images = 1, [self._decode(sample, camera, cv2.IMREAD_COLOR_RGB) for camera in self.cameras]
        if factor == 1:
            decoded = self.layout(meta, [image.shape[:2] for image in images])
        image = render(decoded, images, cv2.INTER_AREA, 0)
        return torch.from_numpy(image).permute(2, 0, 1), decoded if factor == 1 else layout

    def stored_layout(self, meta: dict[str, Any]) -> CameraLayout | None:
        """The layout of this sample's rig at the sizes its calibration (``meta.cameras``) gives; None without one."""
        stored = self._stored_shapes(meta)
        return None if stored is None else self.layout(meta, stored)

    def _jpeg(self, sample: dict[str, Any], camera: str) -> bytes:
        data = sample.get(f"cam_{camera}")
        if data is None:
            raise KeyError(f"sample {sample['__key__']!r} has no camera {camera!r} (field cam_{camera})")
        return data

    def _decode(self, sample: dict[str, Any], camera: str, flags: int) -> np.ndarray:
        image = cv2.imdecode(np.frombuffer(self._jpeg(sample, camera), np.uint8), flags)
        if image is None:
            raise ValueError(f"sample {sample['__key__']!r}: field cam_{camera} is not a decodable JPEG")
        return image

    def _stored_shapes(self, meta: dict[str, Any]) -> list[tuple[int, int]] | None:
        """(height, width) of each camera image as stored, from ``meta.cameras``; None where one has no entry."""
        shapes = []
        for camera in self.cameras:
            entries = _calibrations(meta, camera)
            if not entries:
                return None
            shapes.append(_stored_size(entries))
        return shapes

    def layout(self, meta: dict[str, Any], shapes: Sequence[tuple[int, int]]) -> CameraLayout:
        """The (cached) layout of this sample's rig; warns when it does not fill the model's image."""
        layout = self._rig_layout(meta, shapes)
        if layout.letterboxed and layout not in self._reported:
            self._reported.add(layout)
            self._letterboxed(layout)
        return layout

    def _rig_layout(self, meta: dict[str, Any], shapes: Sequence[tuple[int, int]]) -> CameraLayout:
        fov = self.config.vertical_fov_deg
        cameras = []
        for camera, shape in zip(self.cameras, shapes, strict=True):
            tiles = camera_tiles(meta, camera, shape)
            if fov is None:  # intrinsics do not matter: one layout for every calibration of the rig
                tiles = tuple(Tile(t.x0, t.x1) for t in tiles)
            cameras.append((tuple(shape), tiles))
        try:
            return camera_layout(tuple(cameras), tuple(self.config.image_size), fov)
        except ValueError as err:
            raise ValueError(f"source {self.source!r}, cameras {self.cameras}: {err}") from None

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
            "waypoints": torch.from_numpy(_nan_to_zero(poses[:, :2])),
            "waypoints_valid": torch.from_numpy(valid),
        }
        heading_valid = valid & np.isfinite(poses[:, 2])
        if heading_valid.any():  # a source without headings (WOD-E2E) must not dilute the heading loss of others
            out["headings"] = torch.from_numpy(_nan_to_zero(poses[:, 2]))
            out["headings_valid"] = torch.from_numpy(heading_valid)
        return out

    def perspective_labels(self, sample: dict[str, Any], space: str, layout: CameraLayout) -> dict[str, torch.Tensor]:
        """Depth (float32 metres, 0 = no label) and semantic ids (the stored uint8, :data:`IGNORE_CLASS` = ignore) of
        the single input camera,
        laid out on the input image's pixel grid exactly as the image is, except that a label smaller than the image
        under a plain resize (:attr:`CameraLayout.whole`) stays at its own resolution: the loss resizes it on the
        device (:func:`~lead_s2r.models.inputs.on_image_grid`), as :func:`render` would have."""
        camera = self.cameras[0]
        out = {}
        depth = sample.get(f"depth_{camera}")
        if depth is not None and space in self.config.depth_sources:
            encoding = sample["meta"].get("depth", {})
            metres = depth.astype(np.float32) / 255.0 * float(encoding.get("max_m", self.config.max_depth))
            out["depth"] = torch.from_numpy(_label_on_layout(layout, metres, cv2.INTER_LINEAR, 0.0))
        semantic = sample.get(f"semantic_{camera}")
        if semantic is not None and space in self.config.semantic_classes:
            out["semantic"] = torch.from_numpy(
                _label_on_layout(layout, semantic, cv2.INTER_NEAREST, IGNORE_VALUE["semantic"])
            )
        return out


def _label_on_layout(layout: CameraLayout, label: np.ndarray, interpolation: int, fill: float) -> np.ndarray:
    """``label`` as it is where the loss can resize it on the device (a plain resize up to the model's image),
    else rendered by ``layout`` on the CPU."""
    if layout.whole and label.shape[0] <= layout.image_size[0] and label.shape[1] <= layout.image_size[1]:
        return label
    return render(layout, [label], interpolation, fill)


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
    """Point histogram on ``grid`` (H along +x, W along +y), saturated at :data:`LIDAR_HITS_MAX` hits: uint8 (H, W)
    counts, which the backbone scales to LEAD's [0, 1] (:func:`~lead_s2r.models.inputs.lidar_input`).

    A LEAD frame has about 60,000 points, so every pass over them and every large temporary shows: the fractional
    row and column stay in the points' dtype (float32: a point lands in the cell it always did), the in-grid points
    are picked once and their cell index is formed in that dtype (exact: every index is below 2**24, which
    :func:`_lidar_cells` checks), and the int64 histogram is saturated straight into the uint8 raster.
    """
    h, w = grid.shape
    raster = np.zeros((h, w), np.uint8)
    if points is None or not len(points):
        return raster
    counts = np.bincount(_lidar_cells(points, grid), minlength=h * w).reshape(h, w)
    np.minimum(counts, LIDAR_HITS_MAX, out=raster, casting="unsafe")  # <= LIDAR_HITS_MAX: the cast is exact
    return raster


def lidar_xy(points: np.ndarray | None) -> torch.Tensor:
    """The x, y of LiDAR ``points`` (N, >= 2) for :func:`~lead_s2r.data.device_inputs.rasterize_points` on the
    device, as one contiguous copy (a view would send the whole cloud through a loader worker's shared memory)."""
    if points is None:
        return torch.zeros(0, 2)
    return torch.from_numpy(np.ascontiguousarray(points[:, :2]))


def _lidar_cells(points: np.ndarray, grid: BEVGrid) -> np.ndarray:
    """Flat cell index (row * W + column) of each point of ``points`` on ``grid``; points off the grid dropped."""
    h, w = grid.shape
    if points.dtype not in (np.float32, np.float64):  # the index below is exact in these only
        raise TypeError(f"lidar points must be float32 (the schema's 'lidar' field) or float64, got {points.dtype}")
    if h * w > 2**24:
        raise ValueError(f"BEV grid {h}x{w} has more cells than float32 counts exactly (2**24); use a coarser grid")
    rows = points[:, 0] - grid.x_min  # fractional row and column, in place: one temporary each
    rows *= grid.pixels_per_meter
    cols = points[:, 1] - grid.y_min
    cols *= grid.pixels_per_meter
    inside = rows >= 0  # NaN is outside; inside, truncation is the floor
    inside &= rows < h
    inside &= cols >= 0
    inside &= cols < w
    rows, cols = rows[inside], cols[inside]
    cells = np.trunc(rows, out=rows)
    cells *= w
    cells += np.trunc(cols, out=cols)
    return cells.astype(np.intp)


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
        hit = _radar_hits(radar, boxes)
        speed = np.hypot(boxes[:, 7], boxes[:, 8])
        chosen = np.flatnonzero(hit)[np.argsort(-speed[hit], kind="stable")][:MAX_RADAR_TARGETS]
        targets[: len(chosen)] = np.stack([boxes[chosen, 0], boxes[chosen, 1], speed[chosen]], axis=1)
        valid[: len(chosen)] = True
    return {"radar_targets": torch.from_numpy(targets), "radar_targets_valid": torch.from_numpy(valid)}


def _radar_hits(radar: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(N boxes,) bool: whether any radar point lies inside the box's footprint grown by
    :data:`RADAR_HIT_MARGIN_M`.

    Every (box, point) pair is tested on (boxes, points) planes, x and y apart: a frame has about 60 boxes and 300
    points, and :func:`~lead_s2r.geometry.rotate` of one (boxes, points, 2) array, tested by ``.all`` over its
    2-long last axis, cost six times as much. The arithmetic is rotate's, element for element (same dtype, same
    operations in the same order), so every pair decides as it did. A prefilter (points sorted by x, only pairs
    within reach rotated) saved nothing at these sizes and would need its own rounding argument.
    """
    dx = radar[None, :, 0] - boxes[:, 0, None]
    dy = radar[None, :, 1] - boxes[:, 1, None]
    yaw = -boxes[:, 6, None]
    cos, sin = np.cos(yaw), np.sin(yaw)
    half = boxes[:, 3:5] / 2 + RADAR_HIT_MARGIN_M
    inside = np.abs(cos * dx - sin * dy) <= half[:, 0, None]
    inside &= np.abs(sin * dx + cos * dy) <= half[:, 1, None]
    return inside.any(axis=1)


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
        "route": torch.from_numpy(_nan_to_zero(points)),
        "route_valid": torch.from_numpy(valid),
    }


def _nan_to_zero(values: np.ndarray) -> np.ndarray:
    """float64 ``values`` (resampled, NaN where masked) as float32 with NaN as 0.

    Equal to ``np.nan_to_num(values).astype(np.float32)`` (whose +-float64 max for +-inf round to +-inf in float32)
    in three numpy calls, where ``nan_to_num`` makes a dozen: this runs three times per sample on arrays of a few
    dozen numbers."""
    out = values.astype(np.float32)
    out[np.isnan(out)] = 0.0
    return out


def bev_labels(labels: np.ndarray, spec: dict[str, Any], grid: BEVGrid) -> np.ndarray:
    """Class ids (uint8) of a stored BEV raster (``meta.bev`` spec) at ``grid``'s cell centres; :data:`IGNORE_CLASS`
    outside it.

    The nearest-pixel lookup depends only on the spec, the raster's shape and the grid, so it is computed once
    (:func:`bev_gather_index`) and each sample is one gather."""
    pixel_to_ego = tuple(tuple(float(v) for v in row) for row in spec["pixel_to_ego"])
    index = bev_gather_index(pixel_to_ego, labels.shape[:2], grid)
    values = np.empty(labels.shape[0] * labels.shape[1] + 1, np.uint8)
    values[:-1] = labels.reshape(-1)
    values[-1] = IGNORE_CLASS  # where the index points for cells outside the raster
    return values[index]


@lru_cache(maxsize=64)
def bev_gather_index(pixel_to_ego: tuple[tuple[float, ...], ...], shape: tuple[int, int], grid: BEVGrid) -> np.ndarray:
    """(H, W) flat index into a raster of ``shape`` of every grid cell; ``shape[0] * shape[1]`` (one past the end)
    outside it. :func:`~lead_s2r.geometry.raster_lookup` of a raster of flat indices, so both agree by construction."""
    xs, ys = bev_cell_centres(grid)
    x, y = np.meshgrid(xs, ys, indexing="ij")
    size = shape[0] * shape[1]
    index = raster_lookup(np.arange(size).reshape(shape), np.asarray(pixel_to_ego), x, y, fill=size)
    index.flags.writeable = False  # shared by every sample
    return index


def centernet_targets(boxes: np.ndarray, grid: BEVGrid, num_classes: int) -> dict[str, torch.Tensor]:
    """CenterNet targets on ``grid`` at stride 4: Gaussian heatmaps per class and per-box regression targets.

    With a single class only vehicles are kept (NAVSIM's agent head); otherwise the class is the unified
    :class:`~lead_s2r.schema.BoxClass` id. The first :data:`MAX_BOXES` boxes whose centre falls on the grid count.
    Each Gaussian is drawn only where it is non-zero in float32 (:func:`gaussian_window`), which gives the same
    heatmap as drawing it over the whole grid.
    """
    h, w = grid.shape[0] // CENTERNET_STRIDE, grid.shape[1] // CENTERNET_STRIDE
    cell = CENTERNET_STRIDE / grid.pixels_per_meter
    boxes = np.asarray(boxes, np.float32).reshape(-1, 10)
    labels = boxes[:, 9].astype(np.int64)
    if num_classes == 1:
        keep, labels = labels == BoxClass.VEHICLE, np.zeros_like(labels)
    else:
        keep = labels < num_classes
    row_f, col_f = (boxes[:, 0] - grid.x_min) / cell, (boxes[:, 1] - grid.y_min) / cell
    rows, cols = np.floor(row_f).astype(np.int64), np.floor(col_f).astype(np.int64)
    keep &= (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    chosen = np.flatnonzero(keep)[:MAX_BOXES]
    picked, rows, cols = boxes[chosen], rows[chosen], cols[chosen]
    sigma = np.maximum(np.float32(0.5), np.minimum(picked[:, 3], picked[:, 4]) / cell / 6.0)
    heatmap = np.zeros((num_classes, h, w), np.float32)
    draws = zip(labels[chosen].tolist(), rows.tolist(), cols.tolist(), (2 * sigma**2).tolist(), strict=True)
    for label, row, col, denominator in draws:  # Python numbers: a numpy scalar per box costs more than the draw
        _draw_gaussian(heatmap[label], row, col, denominator)
    offset = np.stack([row_f[chosen] - rows.astype(np.float32), col_f[chosen] - cols.astype(np.float32)], axis=1)
    speed = np.hypot(picked[:, 7].astype(np.float64), picked[:, 8].astype(np.float64))
    regression = {
        "box_index": _first_rows(rows * w + cols, np.int64),
        "box_valid": np.arange(MAX_BOXES) < len(chosen),
        "box_offset": _first_rows(offset, np.float32),
        "box_size": _first_rows(picked[:, 3:5], np.float32),
        "box_yaw": _first_rows(picked[:, 6], np.float32),
        "box_velocity": _first_rows(speed, np.float32),
    }
    return {"box_heatmap": torch.from_numpy(heatmap), **{k: torch.from_numpy(v) for k, v in regression.items()}}


def _first_rows(values: np.ndarray, dtype: type) -> np.ndarray:
    """``values`` (at most :data:`MAX_BOXES` rows) cast to ``dtype`` and zero-padded to :data:`MAX_BOXES` rows."""
    out = np.zeros((MAX_BOXES, *values.shape[1:]), dtype)
    out[: len(values)] = values
    return out


#: exp(-q) rounds to 0 in float32 beyond this q (below half the smallest subnormal, 2**-150: ln 2**-150 = -103.97).
_FLOAT32_EXP_ZERO = 104.0


def _draw_gaussian(heatmap: np.ndarray, row: int, col: int, denominator: float) -> None:
    """``heatmap = max(heatmap, exp(-d^2 / denominator))`` (d: cell distance from (row, col)), in float64 rounded to
    float32, over the window outside which every value is 0 in float32 (:func:`gaussian_window`), cut at the
    heatmap's edges."""
    radius, window = gaussian_window(denominator)
    r0, r1 = max(row - radius, 0), min(row + radius + 1, heatmap.shape[0])
    c0, c1 = max(col - radius, 0), min(col + radius + 1, heatmap.shape[1])
    target = heatmap[r0:r1, c0:c1]
    cut = window[r0 - row + radius : r1 - row + radius, c0 - col + radius : c1 - col + radius]
    np.maximum(target, cut, out=target)


@lru_cache(maxsize=256)
def gaussian_window(denominator: float) -> tuple[int, np.ndarray]:
    """(radius, the (2 radius + 1)^2 float32 window ``exp(-d^2 / denominator)`` around its centre cell), zero in
    float32 beyond ``radius``.

    Cached per denominator: most boxes sit at the 0.5-cell sigma floor (cars, pedestrians), and a dataset's vehicle
    models repeat their sizes, so a few windows serve nearly every box; each value is the same float64 ``exp`` of
    the same integer ``d^2`` whichever box it serves, rounded to float32."""
    radius = math.isqrt(int(_FLOAT32_EXP_ZERO * denominator)) + 1
    offsets = np.arange(-radius, radius + 1)
    window = np.exp(-(offsets[:, None] ** 2 + offsets[None, :] ** 2) / denominator).astype(np.float32)
    window.flags.writeable = False  # shared by every box with this denominator
    return radius, window


#: Fill value of a label a sample lacks: the loss ignores it (masks are False, depth 0 means "no label").
IGNORE_VALUE = {"bev_semantic": IGNORE_CLASS, "semantic": IGNORE_CLASS, "box_heatmap": -1}
#: Labels on the input image's pixel grid, possibly left at their stored (smaller) size: see :func:`on_image_grid`.
IMAGE_ALIGNED = frozenset({"depth", "semantic"})


def collate(samples: list[dict[str, Any]]) -> dict[str, Any]:
    """Stack per-sample tensors into a batch; a label only some samples carry is filled where missing.

    Identity entries (``__key__``, ``__dataset__``) and the inputs left for the device (:data:`RGB_JPEG`,
    :data:`LIDAR_POINTS`) become lists; where only some samples' rigs let their JPEG go encoded, those are decoded
    here. The filler is masked out by construction: validity masks are False, class maps :data:`IGNORE_CLASS`, depth
    0. Perspective labels left at their stored size by rigs of different sizes (one source, several camera rigs) are
    brought onto the image's grid here, as the loss would. In a dataloader worker each tensor is stacked straight
    into shared memory (torch's ``default_collate``), not into private memory that the worker then copies into
    shared memory to send the batch.
    """
    if any(RGB_JPEG in sample for sample in samples) and not all(RGB_JPEG in sample for sample in samples):
        samples = [_decoded(sample) for sample in samples]
    names = set().union(*samples)
    listed = {name for name in names if name.startswith("__")} | ({RGB_JPEG, LIDAR_POINTS} & names)
    batch: dict[str, Any] = {name: [sample[name] for sample in samples] for name in listed}
    for key in sorted(names - listed):
        values = [sample.get(key) for sample in samples]
        if any(value is None for value in values):  # the filler is only built where a sample lacks the label
            template = next(value for value in values if value is not None)
            filler = torch.full_like(template, IGNORE_VALUE.get(key, 0))
            values = [filler if value is None else value for value in values]
        if key in IMAGE_ALIGNED and len({value.shape for value in values}) > 1:  # rigs whose labels differ in size
            size = tuple(batch_image_size(samples))
            values = [on_image_grid(value[None], size)[0] for value in values]
        batch[key] = _stack(key, values)
    return batch


def _stack(key: str, values: list[torch.Tensor]) -> torch.Tensor:
    """One batch tensor; in a loader worker stacked straight into shared memory (torch's ``default_collate``).

    Images are (3, H, W) views of (H, W, 3) pixels, as decoders write them: stacked as (B, H, W, 3), one plain copy,
    and handed on as a channels-last (B, 3, H, W) view (a per-sample planar copy would cost a third of a decode)."""
    if key == "rgb":
        return default_collate([value.permute(1, 2, 0) for value in values]).permute(0, 3, 1, 2)
    return default_collate(values)


def _decoded(sample: dict[str, Any]) -> dict[str, Any]:
    """``sample`` with a JPEG left for the device decoded into ``rgb`` here."""
    if RGB_JPEG not in sample:
        return sample
    sample = dict(sample)
    sample["rgb"] = decode_rgb([sample.pop(RGB_JPEG)], "cpu")[0]
    return sample


def batch_image_size(samples: list[dict[str, Any]]) -> tuple[int, int]:
    """The (H, W) of the input image of a batch's samples (they share the model's ``image_size``)."""
    sample = next((sample for sample in samples if "rgb" in sample or RGB_JPEG in sample), None)
    if sample is None:
        raise KeyError("perspective labels (depth, semantic) need the samples' 'rgb' to know the image grid")
    return tuple(_decoded(sample)["rgb"].shape[-2:])
