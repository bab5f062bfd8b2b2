"""Where each camera's pixels go in the model's input image: the layout of a rig, and applying it (:func:`render`).

Cameras are never squashed: a CARLA 3:1 mosaic stretched into LTFv6's 7:1 input would show every object 2.4x too
wide, a gap between sources that no amount of training closes. Each tile is first cut by its calibration to the
vertical field of view the model asks for (``vertical_fov_deg``, rows around the principal point; padded where the
camera sees less), the tiles are stitched at one height, and the strip is scaled uniformly into ``image_size``,
centred and padded (letterboxed) when its aspect differs by more than :data:`ASPECT_TOLERANCE`. The layout depends
only on the configuration and the rig, so it is computed once per rig (:func:`camera_layout`, cached) and then
applied to the image and its perspective labels alike (:func:`render`).
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import cv2
import numpy as np

#: A camera strip within this relative aspect difference of ``image_size`` is stretched to fill it (a distortion
#: below what anyone sees); beyond it, it is letterboxed.
ASPECT_TOLERANCE = 0.02


@dataclass(frozen=True)
class Tile:
    """One camera tile of a decoded image: columns ``[x0, x1)``; ``fy``, ``cy`` (pixels) from calibration, or None."""

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


@dataclass(frozen=True)
class Calibration:
    """A camera field's ``meta.cameras`` entries, hashable so that a rig's layout is cached by it.

    Attributes:
        size: (height, width) of the stored image the entries describe.
        tiles: per tile left to right, (x0, width, fy, cy) at that size; fy and cy None where the layout does not
            read intrinsics (no vertical field of view asked), so every calibration of a rig shares one layout.
    """

    size: tuple[int, int]
    tiles: tuple[tuple[float, float, float | None, float | None], ...]


def calibration(meta: dict[str, Any], camera: str, intrinsics: bool = True) -> Calibration | None:
    """The calibration of camera field ``camera`` from ``meta.cameras``; None without one."""
    entries = [c for c in meta.get("cameras", []) if c.get("id") == camera]
    if not entries:
        return None
    entries.sort(key=lambda c: c["tile"][0] if "tile" in c else 0)
    width = max((c["tile"][0] + c["tile"][1]) if "tile" in c else c["width"] for c in entries)
    tiles = []
    for c in entries:
        x0, w = c["tile"] if "tile" in c else (0, c["width"])
        fy, cy = (float(c["K"][1][1]), float(c["K"][1][2])) if intrinsics else (None, None)
        tiles.append((x0, w, fy, cy))
    return Calibration((int(entries[0]["height"]), int(width)), tuple(tiles))


def tiles_at(calibration: Calibration | None, shape: tuple[int, int]) -> tuple[Tile, ...]:
    """The tiles of a camera image of ``shape`` (height, width) with ``calibration``, scaled from its stored size:
    a mosaic has one per calibration entry; a camera without calibration is one tile without intrinsics."""
    height, width = shape
    if calibration is None:
        return (Tile(0, width),)
    stored_height, stored_width = calibration.size
    sx, sy = width / stored_width, height / stored_height
    return tuple(
        Tile(round(x0 * sx), round((x0 + w) * sx), None if fy is None else fy * sy, None if cy is None else cy * sy)
        for x0, w, fy, cy in calibration.tiles
    )


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


def label_on_layout(layout: CameraLayout, label: np.ndarray, interpolation: int, fill: float) -> np.ndarray:
    """``label`` as it is where the loss can resize it on the device (a plain resize up to the model's image),
    else rendered by ``layout`` on the CPU."""
    if layout.whole and label.shape[0] <= layout.image_size[0] and label.shape[1] <= layout.image_size[1]:
        return label
    return render(layout, [label], interpolation, fill)


def _resize_height(image: np.ndarray, height: int, interpolation: int) -> np.ndarray:
    width = max(1, round(image.shape[1] * height / image.shape[0]))
    return cv2.resize(image, (width, height), interpolation=interpolation)
