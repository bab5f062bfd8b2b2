"""A sample's cameras decoded into the model's input image: the rig's plan made once, then one decode per camera.

Per sample, :meth:`CameraInput.plan` reads each image's size from its header (:mod:`lead_s2r.image_headers`; JPEG, or
PNG where a test wants lossless pixels) and looks up the rig's :class:`CameraPlan` (cached per rig), which holds the
layout the perspective labels follow and names one decode path, chosen before any pixel is decoded:
- :data:`AS_STORED`: one camera whose JPEG already is the model's image (nothing to crop, stitch or scale) is decoded
  by libjpeg-turbo as it is, without OpenCV's conversions (with ``inputs_on_device`` it is not decoded here at all);
- :data:`REDUCED`: a calibrated rig whose strip is at least 2x the model's image is decoded at 1/2, 1/4 or 1/8 size
  (libjpeg's DCT scaling, OpenCV ``IMREAD_REDUCED_*``, :func:`jpeg_reduction`) and area-resized by the layout of
  the reduced sizes: this differs from the full decode by the rounding of JPEG's scaled IDCT only (bounds pinned in
  tests/test_transform_speed.py). Where the reduced sizes' rounding would move the letterbox (labels laid out at
  full size would not line up), the plan is :data:`FULL` instead;
- :data:`FULL`: every other rig, decoded at full size and laid out (:mod:`lead_s2r.data.camera_layout`).

With ``inputs_on_device`` none of these runs for a rig of JPEGs whose layout the device can apply
(:attr:`CameraPlan.on_device`): its JPEGs go to the training device as bytes with the layout, decoded there at full
size and laid out by area weights (:mod:`lead_s2r.data.device_inputs`).
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

from lead_s2r.data.camera_layout import Calibration, CameraLayout, calibration, camera_layout, render, tiles_at
from lead_s2r.data.device_inputs import decode_rgb, jpeg_tensor, on_device_layout
from lead_s2r.image_headers import jpeg_size, png_size

#: The decode paths (module docstring).
AS_STORED, REDUCED, FULL = "as stored", "reduced", "full"

#: JPEG DCT-domain scalings OpenCV exposes (1/2, 1/4, 1/8), as (factor, imdecode flag without the colour bits).
_JPEG_REDUCTIONS = (
    (8, cv2.IMREAD_REDUCED_COLOR_8 & ~cv2.IMREAD_COLOR),
    (4, cv2.IMREAD_REDUCED_COLOR_4 & ~cv2.IMREAD_COLOR),
    (2, cv2.IMREAD_REDUCED_COLOR_2 & ~cv2.IMREAD_COLOR),
)

#: A rig as the plan is cached by it: per camera field, its stored (height, width) and its calibration.
Rig = tuple[tuple[tuple[int, int], Calibration | None], ...]


def jpeg_reduction(layout: CameraLayout) -> tuple[int, int]:
    """The largest JPEG scale-down (factor, imdecode flag) after which the strip still has at least as many rows and
    columns as the model's image gives it, so the area resize only shrinks; (1, 0) when none fits."""
    (strip_h, strip_w), (box_h, box_w) = layout.strip, layout.box[2:]
    for factor, flag in _JPEG_REDUCTIONS:
        if strip_h >= box_h * factor and strip_w >= box_w * factor:
            return factor, flag
    return 1, 0


@dataclass(frozen=True)
class CameraPlan:
    """How one rig's cameras become the model's image.

    Attributes:
        path: :data:`AS_STORED`, :data:`REDUCED` or :data:`FULL`.
        layout: the layout of the stored images, which the perspective labels follow.
        decoded: the layout of the images as decoded (the reduced sizes on the :data:`REDUCED` path, else ``layout``).
        flag: the imdecode flag of the reduction (0 unless :data:`REDUCED`).
        on_device: the rig's images are JPEGs that the training device can decode and lay out instead of the loader
            (:func:`~lead_s2r.data.device_inputs.on_device_layout`).
    """

    path: str
    layout: CameraLayout
    decoded: CameraLayout
    flag: int = 0
    on_device: bool = False


def rig_layout(rig: Rig, image_size: tuple[int, int], vertical_fov_deg: float | None) -> CameraLayout:
    """The layout of ``rig``'s camera fields at their sizes in the rig (stored or reduced)."""
    return camera_layout(tuple((shape, tiles_at(cal, shape)) for shape, cal in rig), image_size, vertical_fov_deg)


@lru_cache(maxsize=256)
def camera_plan(rig: Rig, image_size: tuple[int, int], vertical_fov_deg: float | None, jpeg: bool) -> CameraPlan:
    """The plan of ``rig`` (its images JPEGs or not) for the model's ``image_size`` (module docstring)."""
    layout = rig_layout(rig, image_size, vertical_fov_deg)
    on_device = jpeg and on_device_layout(layout)
    if layout.identity and jpeg:
        return CameraPlan(AS_STORED, layout, layout, on_device=on_device)
    factor, flag = jpeg_reduction(layout)
    if factor > 1 and all(cal is not None for _, cal in rig):
        reduced_rig = tuple(((math.ceil(h / factor), math.ceil(w / factor)), cal) for (h, w), cal in rig)
        reduced = rig_layout(reduced_rig, image_size, vertical_fov_deg)  # libjpeg rounds scaled sizes up
        if reduced.box == layout.box:
            return CameraPlan(REDUCED, layout, reduced, flag, on_device)
    return CameraPlan(FULL, layout, layout, on_device=on_device)


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

    def plan(self, sample: dict[str, Any]) -> CameraPlan:
        """The plan of ``sample``'s rig, from its calibration and its JPEGs' stored sizes (headers, not pixels)."""
        stored = [self.stored(sample, camera) for camera in self.cameras]
        return self.plan_for(sample["meta"], [shape for shape, _ in stored], all(jpeg for _, jpeg in stored))

    def plan_for(self, meta: dict[str, Any], shapes: Sequence[tuple[int, int]], jpeg: bool = True) -> CameraPlan:
        """The plan of the rig ``meta`` calibrates, its camera fields stored at ``shapes`` (JPEGs or not); warns
        (once per layout) when the layout does not fill the model's image."""
        intrinsics = self.vertical_fov_deg is not None  # else one layout serves every calibration of the rig
        rig = tuple(
            (tuple(shape), calibration(meta, camera, intrinsics))
            for camera, shape in zip(self.cameras, shapes, strict=True)
        )
        try:
            plan = camera_plan(rig, tuple(self.image_size), self.vertical_fov_deg, jpeg)
        except ValueError as err:
            raise ValueError(f"source {self.source!r}, cameras {list(self.cameras)}: {err}") from None
        if plan.layout.letterboxed and plan.layout not in self._reported:
            self._letterboxed(plan.layout)
            self._reported.add(plan.layout)
        return plan

    def image(self, sample: dict[str, Any], plan: CameraPlan) -> torch.Tensor:
        """uint8 (3, H, W) RGB of ``sample``'s cameras, each decoded once by ``plan``'s path."""
        if plan.path == AS_STORED:
            data = self.jpeg(sample, self.cameras[0])
            try:
                return decode_rgb([jpeg_tensor(data)], "cpu")[0]
            except RuntimeError as err:
                raise ValueError(f"{self.field(sample, self.cameras[0])} is not a decodable JPEG ({err})") from None
        flags = cv2.IMREAD_COLOR_RGB | plan.flag
        images = [self.decode(sample, camera, flags) for camera in self.cameras]
        if [image.shape[:2] for image in images] != list(plan.decoded.sizes):
            raise ValueError(f"sample {sample['__key__']!r}: a camera decodes to another size than its header says")
        return torch.from_numpy(render(plan.decoded, images, cv2.INTER_AREA, 0)).permute(2, 0, 1)

    def jpeg(self, sample: dict[str, Any], camera: str) -> bytes:
        data = sample.get(f"cam_{camera}")
        if data is None:
            raise KeyError(f"sample {sample['__key__']!r} has no camera {camera!r} (field cam_{camera})")
        return data

    def stored(self, sample: dict[str, Any], camera: str) -> tuple[tuple[int, int], bool]:
        """(height, width) of camera field ``camera`` as stored and whether it is a JPEG, from its header."""
        encoded = self.jpeg(sample, camera)
        size, jpeg = jpeg_size(encoded), True
        if size is None:
            size, jpeg = png_size(encoded), False
        if size is None:
            raise ValueError(f"{self.field(sample, camera)} is not a decodable JPEG (no frame header)")
        return (size[1], size[0]), jpeg

    def decode(self, sample: dict[str, Any], camera: str, flags: int) -> np.ndarray:
        image = cv2.imdecode(np.frombuffer(self.jpeg(sample, camera), np.uint8), flags)
        if image is None:
            raise ValueError(f"{self.field(sample, camera)} is not a decodable JPEG")
        return image

    @staticmethod
    def field(sample: dict[str, Any], camera: str) -> str:
        return f"sample {sample['__key__']!r}: field cam_{camera}"

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
            stacklevel=4,
        )
