"""A sample's cameras decoded into the model's input image, by one of three named paths.

- :meth:`CameraInput.as_stored`: one camera whose JPEG already is the model's image (nothing to crop, stitch or
  scale) is decoded by libjpeg-turbo as it is, without OpenCV's conversions.
- :meth:`CameraInput.reduced`: where the calibration gives the stored sizes and the model's image is at least 2x
  smaller, JPEGs are decoded at 1/2, 1/4 or 1/8 size (libjpeg's DCT scaling, OpenCV ``IMREAD_REDUCED_*``,
  :func:`jpeg_reduction`) and area-resized: this differs from the full decode by the rounding of JPEG's scaled IDCT
  only (bounds pinned in tests/test_transform_speed.py).
- :meth:`CameraInput.full`: every other rig, decoded at full size and laid out (:mod:`lead_s2r.data.camera_layout`).

The layout of a rig comes from its calibration (``meta.cameras``) before decoding where it can, so a path that finds
the stored sizes were not what the calibration said falls back to the full decode rather than misplace labels.
"""

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import torch

from lead_s2r.data.camera_layout import CameraLayout, Tile, camera_layout, camera_tiles, render, stored_shape
from lead_s2r.data.device_inputs import decode_rgb, jpeg_tensor

#: JPEG DCT-domain scalings OpenCV exposes (1/2, 1/4, 1/8), as (factor, imdecode flag without the colour bits).
_JPEG_REDUCTIONS = (
    (8, cv2.IMREAD_REDUCED_COLOR_8 & ~cv2.IMREAD_COLOR),
    (4, cv2.IMREAD_REDUCED_COLOR_4 & ~cv2.IMREAD_COLOR),
    (2, cv2.IMREAD_REDUCED_COLOR_2 & ~cv2.IMREAD_COLOR),
)


def jpeg_reduction(layout: CameraLayout) -> tuple[int, int]:
    """The largest JPEG scale-down (factor, imdecode flag) after which the strip still has at least as many rows and
    columns as the model's image gives it, so the area resize only shrinks; (1, 0) when none fits."""
    (strip_h, strip_w), (box_h, box_w) = layout.strip, layout.box[2:]
    for factor, flag in _JPEG_REDUCTIONS:
        if strip_h >= box_h * factor and strip_w >= box_w * factor:
            return factor, flag
    return 1, 0


@dataclass
class CameraInput:
    """Camera fields of one source stitched left to right into the model's ``image_size``.

    Args:
        source: the source name, for messages.
        cameras: camera fields, without the ``cam_`` prefix.
        image_size: the model's (H, W).
        vertical_fov_deg: rows kept around each tile's principal point (None: all rows).
        equal_tiles: the model cuts equal tiles from a mosaic that fills ``image_size`` (the camera ablations), so a
            letterboxed rig is an error, not a warning.
    """

    source: str
    cameras: Sequence[str]
    image_size: tuple[int, int]
    vertical_fov_deg: float | None = None
    equal_tiles: bool = False
    _reported: set[CameraLayout] = field(default_factory=set, init=False, repr=False)  # letterboxed layouts warned of

    def image(self, sample: dict[str, Any], stored: CameraLayout | None) -> tuple[torch.Tensor, CameraLayout]:
        """uint8 (3, H, W) RGB of ``sample``'s cameras, and the layout of the full-size images (which perspective
        labels follow), given the rig's layout at its stored sizes (:meth:`stored_layout`; None: no calibration)."""
        if stored is not None and stored.identity:
            image = self.as_stored(sample, stored)
            if image is not None:
                return image, stored
        if stored is not None and jpeg_reduction(stored)[0] > 1:
            image = self.reduced(sample, stored)
            if image is not None:
                return image, stored
        return self.full(sample)

    def as_stored(self, sample: dict[str, Any], stored: CameraLayout) -> torch.Tensor | None:
        """The one camera's JPEG decoded as it is; None where it is not the size its calibration says."""
        try:
            image = decode_rgb([jpeg_tensor(self.jpeg(sample, self.cameras[0]))], "cpu")[0]
        except RuntimeError as err:
            raise ValueError(
                f"sample {sample['__key__']!r}: field cam_{self.cameras[0]} is not a decodable JPEG ({err})"
            ) from None
        return image if tuple(image.shape[1:]) == stored.image_size else None

    def reduced(self, sample: dict[str, Any], stored: CameraLayout) -> torch.Tensor | None:
        """The cameras decoded at :func:`jpeg_reduction` of ``stored`` and laid out; None where the reduced sizes'
        rounding moves the letterbox (labels laid out at full size would not line up)."""
        _, flag = jpeg_reduction(stored)
        images = [self.decode(sample, camera, cv2.IMREAD_COLOR_RGB | flag) for camera in self.cameras]
        layout = self.rig_layout(sample["meta"], [image.shape[:2] for image in images])
        if layout.box != stored.box:
            return None
        return torch.from_numpy(render(layout, images, cv2.INTER_AREA, 0)).permute(2, 0, 1)

    def full(self, sample: dict[str, Any]) -> tuple[torch.Tensor, CameraLayout]:
        """The cameras decoded at full size and laid out, with the layout of their decoded sizes."""
        images = [self.decode(sample, camera, cv2.IMREAD_COLOR_RGB) for camera in self.cameras]
        layout = self.layout(sample["meta"], [image.shape[:2] for image in images])
        return torch.from_numpy(render(layout, images, cv2.INTER_AREA, 0)).permute(2, 0, 1), layout

    def stored_layout(self, meta: dict[str, Any]) -> CameraLayout | None:
        """The layout of this sample's rig at the sizes its calibration (``meta.cameras``) gives; None without one."""
        shapes = [stored_shape(meta, camera) for camera in self.cameras]
        return None if None in shapes else self.layout(meta, shapes)

    def jpeg(self, sample: dict[str, Any], camera: str) -> bytes:
        data = sample.get(f"cam_{camera}")
        if data is None:
            raise KeyError(f"sample {sample['__key__']!r} has no camera {camera!r} (field cam_{camera})")
        return data

    def decode(self, sample: dict[str, Any], camera: str, flags: int) -> np.ndarray:
        image = cv2.imdecode(np.frombuffer(self.jpeg(sample, camera), np.uint8), flags)
        if image is None:
            raise ValueError(f"sample {sample['__key__']!r}: field cam_{camera} is not a decodable JPEG")
        return image

    def layout(self, meta: dict[str, Any], shapes: Sequence[tuple[int, int]]) -> CameraLayout:
        """The (cached) layout of this sample's rig; warns when it does not fill the model's image."""
        layout = self.rig_layout(meta, shapes)
        if layout.letterboxed and layout not in self._reported:
            self._reported.add(layout)
            self._letterboxed(layout)
        return layout

    def rig_layout(self, meta: dict[str, Any], shapes: Sequence[tuple[int, int]]) -> CameraLayout:
        """The (cached) layout of the rig at decoded ``shapes``, without the letterbox warning."""
        fov = self.vertical_fov_deg
        cameras = []
        for camera, shape in zip(self.cameras, shapes, strict=True):
            tiles = camera_tiles(meta, camera, shape)
            if fov is None:  # intrinsics do not matter: one layout for every calibration of the rig
                tiles = tuple(Tile(t.x0, t.x1) for t in tiles)
            cameras.append((tuple(shape), tiles))
        try:
            return camera_layout(tuple(cameras), tuple(self.image_size), fov)
        except ValueError as err:
            raise ValueError(f"source {self.source!r}, cameras {list(self.cameras)}: {err}") from None

    def _letterboxed(self, layout: CameraLayout) -> None:
        (strip_h, strip_w), (h, w) = layout.strip, layout.image_size
        y0, x0, box_h, box_w = layout.box
        if self.equal_tiles:
            raise ValueError(
                f"source {self.source!r}: the camera ablations (camera_tiles, use_tiles, fov_fraction) cut equal "
                f"tiles from a mosaic that fills image_size, but this source's {strip_w}x{strip_h} strip is "
                f"letterboxed into {w}x{h}; set image_size to the strip's aspect"
            )
        warnings.warn(
            f"source {self.source!r}: cameras {list(self.cameras)} make a {strip_w}x{strip_h} strip (aspect "
            f"{strip_w / strip_h:.2f}) but the model's image is {w}x{h} (aspect {w / h:.2f}); letterboxed into "
            f"{box_w}x{box_h} at x={x0}, y={y0} instead of squashed. Match image_size (or vertical_fov_deg) to "
            "this rig to use every input pixel",
            stacklevel=3,
        )
