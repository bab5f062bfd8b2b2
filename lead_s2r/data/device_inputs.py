"""Inputs the loader leaves raw on a GPU run (``DriveDataModule(inputs_on_device=...)``) and the training device
builds before the batch moves: camera JPEGs decoded and laid out (``rgb_jpeg`` + ``rgb_layout`` -> ``rgb``) and
LiDAR points rasterised (``lidar_points`` -> ``lidar_bev``).

Why: the loader's CPU per sample sets how many cores each GPU needs (docs/benchmarks.md, "Training loader"). The
1152x384 CARLA mosaic costs it 0.7-1.5 ms a sample to decode; WOD-E2E's three 972x1079 front cameras about 7 ms to
decode and lay out into LTFv6's 972x360; a LEAD frame's 60,000 LiDAR points 0.6 ms to rasterise. Left raw, the
images cross to the device as JPEG bytes, and nvJPEG (one call per batch), a few matrix products and one
``bincount`` per batch do the work there.

Camera layout on the device: each sample carries its cameras' JPEGs and its rig's
:class:`~lead_s2r.data.camera_layout.CameraLayout` (the plan the loader would render by). Every crop, stitch and
scale of :func:`~lead_s2r.data.camera_layout.render` is linear, so a layout becomes, per band of a camera, a source
rectangle and two area-weight matrices (rows, columns: :func:`area_weights`, exactly the weights of OpenCV's
``INTER_AREA`` when it shrinks, the two stages of a band scaled to the strip's height composed into one), and the
device computes ``rows @ pixels @ columns.T`` per band into the model's image (zero where letterboxed), rounded to
uint8 as the loader's image is. Only layouts that never enlarge take this route (OpenCV's ``INTER_AREA``
interpolates when it enlarges); others, and PNG cameras, are laid out in the loader.

What differs from the loader's image, and by how much (docs/benchmarks.md, "WOD-E2E: camera layout on the device"):
the device decodes each JPEG at full size, while the loader decodes a rig whose strip is at least twice the model's
image at 1/2-1/8 size (libjpeg's DCT scaling, ``camera_input.REDUCED``) before its area resize. Against a full
decode and OpenCV's ``INTER_AREA`` (``camera_input.FULL``) the device layout is within a level or two (float
weights without OpenCV's intermediate rounding; pinned in tests/test_inputs_on_device.py); against the reduced
decode it differs as the reduced decode differs from the full one.

The raster is bit for bit the loader's (:func:`~lead_s2r.data.lidar.rasterize_lidar`: the same float32
arithmetic). On the CPU the decoder is libjpeg-turbo, pixel for pixel OpenCV's decode; nvJPEG's pixels may differ
by a level or two (its own IDCT and chroma upsampling), and the first image a run decodes on a GPU is held to the
CPU's decode and layout (:func:`check_device_decode`). torchvision's CUDA decoder writes on a stream of its own that
does not wait for the caller's (pytorch/vision#9606: corrupted pixels on an H100 when the caching allocator hands it
memory that queued kernels still read), so :func:`decode_rgb` drains the caller's stream first.
"""

import warnings
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import torch
from torch import Tensor
from torchvision.io import ImageReadMode, decode_jpeg

from lead_s2r.data.camera_layout import CameraLayout
from lead_s2r.models.config import BEVGrid
from lead_s2r.models.inputs import LIDAR_HITS_MAX, Batch

#: Batch key of input images left JPEG-encoded by the loader: per sample, its cameras' JPEGs as 1-D uint8 CPU tensors
#: (:func:`decode_images`).
RGB_JPEG = "rgb_jpeg"
#: Batch key of each sample's :class:`~lead_s2r.data.camera_layout.CameraLayout`, beside :data:`RGB_JPEG`.
RGB_LAYOUT = "rgb_layout"
#: Batch key of LiDAR points left for the device to rasterise: a list of (N, 2) float CPU tensors of x, y
#: (:func:`rasterize_points`).
LIDAR_POINTS = "lidar_points"
#: Mean absolute difference (levels of 255) beyond which a device's decode is not libjpeg-turbo's up to rounding
#: (nvJPEG's IDCT and chroma upsampling move pixels by a level or two, far less on average).
DEVICE_DECODE_TOLERANCE = 2.0


def jpeg_tensor(data: bytes) -> Tensor:
    """JPEG bytes as the 1-D uint8 tensor the decoders take (a copy: torch refuses to wrap read-only bytes)."""
    return torch.frombuffer(bytearray(data), dtype=torch.uint8)


def decode_rgb(encoded: list[Tensor], device: torch.device | str) -> list[Tensor]:
    """JPEGs (1-D uint8 CPU tensors) as (3, H, W) uint8 RGB on ``device``: nvJPEG on CUDA, one call for them all;
    libjpeg-turbo on the CPU, pixel for pixel OpenCV's decode. On CUDA the caller's stream is drained first (module
    docstring); training syncs once a step anyway (the progress bar reads the loss), so this costs little overlap."""
    device = torch.device(device)
    if device.type == "cuda":
        torch.cuda.current_stream(device).synchronize()
    with warnings.catch_warnings():  # torchvision 0.29 deprecates its codecs for torchcodec, whose wheels each fit
        warnings.simplefilter("ignore", DeprecationWarning)  # one torch release only; ours follow torchvision's range
        return decode_jpeg(list(encoded), mode=ImageReadMode.RGB, device=device)


def on_device_layout(layout: CameraLayout) -> bool:
    """Whether the device can lay out ``layout`` as the loader does: nothing to do, or no scaling that enlarges (the
    area weights are then OpenCV's ``INTER_AREA``, which interpolates instead where it enlarges)."""
    if layout.identity:
        return True
    (strip_h, strip_w), (box_h, box_w) = layout.strip, layout.box[2:]
    if strip_h < box_h or strip_w < box_w:
        return False
    # a band taller than the strip's first band shrinks to its height, in both axes
    return all(band.bottom - band.top >= strip_h for bands in layout.bands for band in bands)


def area_weights(source: int, target: int) -> np.ndarray:
    """(target, source) float64 weights of an area resize from ``source`` to ``target`` <= ``source`` pixels: output
    pixel j averages the source interval [j s, (j + 1) s), s = source / target, each source pixel weighted by its
    overlap (OpenCV's ``INTER_AREA`` when shrinking, non-integer ratios included)."""
    scale = source / target
    start = np.arange(target)[:, None] * scale
    pixel = np.arange(source)[None, :]
    overlap = np.minimum(start + scale, pixel + 1) - np.maximum(start, pixel)
    return np.clip(overlap, 0.0, None) / scale


@dataclass(frozen=True)
class BandWeights:
    """One band of a layout as the device applies it: ``rows @ image[camera][:, top:bottom, x0:x1] @ columns.T`` is
    added to the model image's rows ``[y0, y0 + len(rows))`` and columns ``[out_x0, out_x0 + len(columns))``."""

    camera: int
    top: int
    bottom: int
    x0: int
    x1: int
    y0: int
    out_x0: int
    rows: Tensor
    columns: Tensor


@lru_cache(maxsize=64)
def band_weights(layout: CameraLayout, device: torch.device) -> tuple[BandWeights, ...]:
    """The bands of ``layout`` (:func:`on_device_layout`) as source rectangles and area weights on ``device``: the
    strip's resize into the box composed with a band's own resize to the strip's height, as
    :func:`~lead_s2r.data.camera_layout.render` does them one after the other; padding rows (a field of view beyond
    the camera's) weigh nothing, as the loader's zero fill does."""
    y0, box_x0, box_h, box_w = layout.box
    strip_h, strip_w = layout.strip
    strip_rows, strip_columns = area_weights(strip_h, box_h), area_weights(strip_w, box_w)
    offset, out = 0, []
    for camera, (size, bands) in enumerate(zip(layout.sizes, layout.bands, strict=True)):
        for band in bands:
            height, width = band.bottom - band.top, band.x1 - band.x0
            scaled = width if height == strip_h else max(1, round(width * strip_h / height))
            rows = strip_rows @ area_weights(height, strip_h)
            columns = strip_columns[:, offset : offset + scaled] @ area_weights(width, scaled)
            offset += scaled
            top, bottom = max(band.top, 0), min(band.bottom, size[0])
            rows = rows[:, top - band.top : bottom - band.top]
            used = np.flatnonzero(columns.any(axis=1))
            columns = columns[used[0] : used[-1] + 1]
            out.append(
                BandWeights(
                    camera, top, bottom, band.x0, band.x1, y0, box_x0 + int(used[0]),
                    torch.from_numpy(rows).float().to(device), torch.from_numpy(columns).float().to(device),
                )
            )  # fmt: skip
    return tuple(out)


def lay_out(cameras: list[Tensor], layout: CameraLayout) -> Tensor:
    """The model images (N, 3, H, W) uint8 of N samples of one rig: ``cameras`` holds per camera field its decoded
    (N, 3, h, w) uint8 images, laid out by ``layout`` (:func:`band_weights`) on their device."""
    if layout.identity:
        return cameras[0]
    first = cameras[0]
    image = torch.zeros((len(first), 3, *layout.image_size), dtype=torch.float32, device=first.device)
    saved = torch.get_float32_matmul_precision()
    torch.set_float32_matmul_precision("highest")  # not TF32, which a run may allow: 10 mantissa bits move pixels
    try:
        for band in band_weights(layout, first.device):
            pixels = cameras[band.camera][..., band.top : band.bottom, band.x0 : band.x1].float()
            rows, columns = band.rows.shape[0], band.columns.shape[0]
            image[..., band.y0 : band.y0 + rows, band.out_x0 : band.out_x0 + columns] += (
                band.rows @ pixels @ band.columns.T
            )
    finally:
        torch.set_float32_matmul_precision(saved)
    return image.round_().clamp_(0, 255).to(torch.uint8)


def decode_images(batch: Batch, device: torch.device | str) -> Batch:
    """``batch`` with its :data:`RGB_JPEG` cameras decoded (:func:`decode_rgb`) and laid out by their :data:`RGB_LAYOUT`
    into ``rgb`` on ``device``; a batch without them is returned as it is. Every JPEG must decode to the size its layout
    says (its sample's calibration, which the loader read from the JPEG's header)."""
    if RGB_JPEG not in batch:
        return batch
    batch = dict(batch)
    encoded, layouts = batch.pop(RGB_JPEG), batch.pop(RGB_LAYOUT)
    keys = batch.get("__key__", [str(i) for i in range(len(encoded))])
    try:
        decoded = iter(decode_rgb([jpeg for cameras in encoded for jpeg in cameras], device))
    except RuntimeError as err:
        raise ValueError(f"a camera JPEG of the samples {keys} is not decodable: {err}") from None
    per_sample = [[next(decoded) for _ in cameras] for cameras in encoded]
    for key, images, layout in zip(keys, per_sample, layouts, strict=True):
        sizes = [tuple(image.shape[-2:]) for image in images]
        if sizes != list(layout.sizes):
            raise ValueError(
                f"sample {key}: its camera JPEGs decode to {sizes}, but their headers said {list(layout.sizes)}; "
                "re-convert the sample"
            )
    rigs: dict[CameraLayout, list[int]] = {}
    for index, layout in enumerate(layouts):
        rigs.setdefault(layout, []).append(index)
    rgb: list[Tensor] = [torch.empty(0)] * len(encoded)
    for layout, indices in rigs.items():
        cameras = [torch.stack([per_sample[i][c] for i in indices]) for c in range(len(layout.sizes))]
        for index, image in zip(indices, lay_out(cameras, layout), strict=True):
            rgb[index] = image
    batch["rgb"] = torch.stack(rgb)
    return batch


def check_device_decode(encoded: list[Tensor], layout: CameraLayout, decoded: Tensor) -> float:
    """Mean absolute difference between ``decoded`` (one sample's cameras decoded and laid out on a device) and the
    CPU's (libjpeg-turbo); raises when it exceeds :data:`DEVICE_DECODE_TOLERANCE`, a broken device decoder."""
    reference = decode_images({RGB_JPEG: [encoded], RGB_LAYOUT: [layout]}, "cpu")["rgb"][0]
    difference = (decoded.cpu().int() - reference.int()).abs().float().mean().item()
    if difference > DEVICE_DECODE_TOLERANCE:
        raise RuntimeError(
            f"the {decoded.device} JPEG decoder's pixels differ from libjpeg-turbo's by {difference:.2f} levels on "
            f"average (more than {DEVICE_DECODE_TOLERANCE}): its decode is broken on this machine; train with "
            "--data.inputs_on_device=false to decode in the loader"
        )
    return difference


def rasterize_points(batch: Batch, grid: BEVGrid, device: torch.device | str) -> Batch:
    """``batch`` with its :data:`LIDAR_POINTS` turned into ``lidar_bev`` on ``device``: hits per cell of ``grid``,
    saturated at :data:`LIDAR_HITS_MAX`, (B, 1, H, W) uint8, bit for bit the loader's
    :func:`~lead_s2r.data.lidar.rasterize_lidar` (the same float32 arithmetic, truncation as the floor inside
    the grid); a batch without them is returned as it is. One ``bincount`` for the batch."""
    if LIDAR_POINTS not in batch:
        return batch
    batch = dict(batch)
    clouds = batch.pop(LIDAR_POINTS)
    h, w = grid.shape
    points = torch.cat(list(clouds)).to(device, non_blocking=True)
    sample = torch.repeat_interleave(torch.arange(len(clouds)), torch.tensor([len(c) for c in clouds])).to(device)
    rows = (points[:, 0] - grid.x_min) * grid.pixels_per_meter
    cols = (points[:, 1] - grid.y_min) * grid.pixels_per_meter
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)  # NaN is outside
    cells = (sample[inside] * h + rows[inside].long()) * w + cols[inside].long()
    counts = torch.bincount(cells, minlength=len(clouds) * h * w)
    batch["lidar_bev"] = counts.clamp_(max=LIDAR_HITS_MAX).to(torch.uint8).view(len(clouds), 1, h, w)
    return batch
