"""The model-input batch contract: what ``data/`` transforms must produce and what models and losses read.

One batch holds samples of one source (dataset), so shapes and grids are homogeneous; the LightningModule receives
``{source: Batch}``. Geometry is in the ISO 8855 ego frame (x forward, y left, metres, radians) with the origin at
the rear axle; BEV arrays follow :class:`~lead_s2r.models.config.BEVGrid` (H along +x, W along +y).
Every ``*_valid`` mask is bool and marks entries that carry a label; invalid entries may hold any finite value.

The contract is lean because the loader builds and stacks every byte of it on the CPU, per sample, beside the GPU:
images stay uint8 (normalised in the model); the LiDAR raster is uint8 hit counts saturated at
:data:`LIDAR_HITS_MAX` (scaled to [0, 1] by the backbone, :func:`lidar_input`); class maps are the stored uint8 ids
with :data:`IGNORE_CLASS` for "no label" (no widened copy: the losses widen them on the device, :func:`class_ids`);
and ``depth``/``semantic`` may stay smaller than the image when the image is a plain resize of one camera: the
loss resizes them onto the image's grid on the device (:func:`on_image_grid`) exactly as the loader
would have (bilinear / nearest, pixel centres aligned), so a depth stored at 1/4 size is not shipped 16x larger.
Float rasters and signed class maps (-1 = ignore) are accepted too, so a batch built by hand needs no uint8 coding.

Where a camera's stored JPEG already is the model's image (one camera at ``image_size``, nothing to crop or scale),
the loader may leave it encoded: ``rgb_jpeg`` (:data:`RGB_JPEG`) carries each sample's JPEG bytes, and
:func:`decode_images` turns them into ``rgb`` on the training device before the forward, with nvJPEG on a GPU.
That takes the largest decode of a CARLA sample off the loader's CPU and sends 12-200 KB to the device instead of
1.3 MB. nvJPEG's pixels may differ from libjpeg-turbo's by a level or two (its IDCT and chroma upsampling are its
own); on the CPU the decode is libjpeg-turbo's, equal to the loader's. Likewise ``lidar_points`` (:data:`LIDAR_POINTS`)
carries each sample's LiDAR x, y for :func:`rasterize_points`, one ``bincount`` for the batch on the device, bit for
bit the loader's raster (60,000 points of a LEAD frame cost the loader 0.6 ms).
"""

import warnings
from collections.abc import Mapping
from typing import Any, TypedDict

import torch
import torch.nn.functional as F
from torch import Tensor
from torchvision.io import ImageReadMode, decode_jpeg

from lead_s2r.models.config import BEVGrid

#: LiDAR hits per BEV cell at which the raster saturates (LEAD's ``rasterize_lidar``: clip at 5, scale to [0, 1]).
LIDAR_HITS_MAX = 5
#: Class id of "no label" in a uint8 class map (no class table uses it: they stop far below 255).
IGNORE_CLASS = 255
#: Batch key of input images left JPEG-encoded by the loader: a list of 1-D uint8 CPU tensors (:func:`decode_images`).
RGB_JPEG = "rgb_jpeg"
#: Batch key of LiDAR points left for the device to rasterise: a list of (N, 2) float32 CPU tensors of x, y
#: (:func:`rasterize_points`).
LIDAR_POINTS = "lidar_points"
#: Mean absolute difference (levels of 255) beyond which a device's decode is not libjpeg-turbo's up to rounding
#: (nvJPEG's IDCT and chroma upsampling move pixels by a level or two, far less on average).
DEVICE_DECODE_TOLERANCE = 2.0


class Batch(TypedDict, total=False):
    """Inputs and targets of one per-source batch (B samples). Keys a source does not have are left out."""

    __key__: list[str]  # sample keys, for predictions
    # --- inputs
    rgb: Tensor  # (B, 3, H, W) uint8 (or float in [0, 255]), RGB order; normalised inside the model
    rgb_jpeg: list[Tensor]  # instead of rgb: each sample's JPEG bytes (1-D uint8, CPU), see decode_images
    lidar_bev: Tensor  # (B, C, Hb, Wb) uint8 hits per cell, 0..LIDAR_HITS_MAX (or float in [0, 1]) (TFv6 only)
    lidar_points: list[Tensor]  # instead of lidar_bev: each sample's (N, 2) x, y, see rasterize_points
    speed: Tensor  # (B,) m/s
    acceleration: Tensor  # (B, 2) m/s^2, [ax, ay] in the ego frame
    command: Tensor  # (B,) int64 in the 4-way {UNKNOWN, LEFT, STRAIGHT, RIGHT} (schema.command4)
    target_points: Tensor  # (B, 3, 2) previous, current, next route target point, metres
    target_points_valid: Tensor  # (B, 3)
    radar: Tensor  # (B, N, 5) x, y, z, radial velocity, sensor index
    radar_valid: Tensor  # (B, N)
    # --- planning targets
    waypoints: Tensor  # (B, T, 2) on the source's TrajectoryGrid
    waypoints_valid: Tensor  # (B, T)
    headings: Tensor  # (B, T) yaw, radians
    headings_valid: Tensor  # (B, T)
    route: Tensor  # (B, K, 2) route checkpoints ahead
    route_valid: Tensor  # (B, K)
    target_speed: Tensor  # (B,) expert target speed, m/s (two-hot encoded over the speed classes by the loss)
    target_speed_valid: Tensor  # (B,)
    # --- perception targets
    bev_semantic: Tensor  # (B, Hs, Ws) uint8 class ids over the BEV grid, IGNORE_CLASS = ignore (or signed, -1)
    box_heatmap: Tensor  # (B, C, h, w) float CenterNet Gaussian heatmap on the head's grid (stride 4)
    box_index: Tensor  # (B, M) int64 flat index of each box centre cell into h * w
    box_valid: Tensor  # (B, M)
    box_offset: Tensor  # (B, M, 2) sub-cell centre offset
    box_size: Tensor  # (B, M, 2) length, width, metres
    box_yaw: Tensor  # (B, M) radians
    box_velocity: Tensor  # (B, M) m/s
    depth: Tensor  # (B, Hd, Wd) float32 metres, 0 = no label; (Hd, Wd) = (H, W) or smaller (see below)
    semantic: Tensor  # (B, Hd, Wd) uint8 perspective class ids, IGNORE_CLASS = ignore (or signed, -1)
    radar_targets: Tensor  # (B, R, 3) x, y, speed of objects seen by radar
    radar_targets_valid: Tensor  # (B, R)


#: Loss terms by group: the planner's outputs, and the perception heads' (``supervise:`` names these groups).
PLANNING_TASKS = frozenset({"waypoints", "headings", "route", "target_speed"})
PERCEPTION_TASKS = frozenset({"bev_semantic", "boxes", "depth", "semantic", "radar"})


def target_point_range(info: Mapping[str, Any]) -> tuple[tuple[float, float], tuple[float, float]]:
    """``(low, high)`` for ``TFv6Config.target_point_low/high`` from a converted dataset's info.json.

    Reads ``info["statistics"]["target_points"]["low"|"high"]`` ([x, y] each, e.g. 1st/99th percentiles).
    """
    try:
        stats = info["statistics"]["target_points"]
        low, high = stats["low"], stats["high"]
    except (KeyError, TypeError) as err:
        raise KeyError(f"info.json has no statistics.target_points.low/high ({err})") from None
    if not all(h > lo for lo, h in zip(low, high, strict=True)):
        raise ValueError(f"info.json statistics.target_points: high {high} must exceed low {low}")
    return (float(low[0]), float(low[1])), (float(high[0]), float(high[1]))


def on_image_grid(label: Tensor, size: tuple[int, int]) -> Tensor:
    """A (B, h, w) perspective label the loader left at its own resolution, on the input image's ``size`` as the
    loader's ``cv2.resize`` would have put it: bilinear with pixel centres aligned for depth (float), nearest for
    class ids (both take the floor of the scaled index, as OpenCV's INTER_NEAREST does). Equal to float32 rounding."""
    if tuple(label.shape[-2:]) == tuple(size):
        return label
    if label.is_floating_point():
        return F.interpolate(label[:, None], size=size, mode="bilinear", align_corners=False)[:, 0]
    return F.interpolate(label[:, None].float(), size=size, mode="nearest")[:, 0].to(label.dtype)


def lidar_input(lidar_bev: Tensor, dtype: torch.dtype) -> Tensor:
    """The LiDAR raster as the network reads it: hit counts / :data:`LIDAR_HITS_MAX` in ``dtype`` (a float raster
    is taken as already scaled). In float32 this is bit-identical to LEAD's float32 ``min(k, 5) / 5``."""
    if lidar_bev.is_floating_point():
        return lidar_bev.to(dtype)
    return (lidar_bev.float() / LIDAR_HITS_MAX).to(dtype)


def class_ids(labels: Tensor) -> Tensor:
    """A class map as int64 ids with -1 where there is no label: a uint8 map marks it :data:`IGNORE_CLASS`, a
    signed one -1."""
    ids = labels.long()
    if labels.dtype == torch.uint8:
        ids = ids.masked_fill(labels == IGNORE_CLASS, -1)
    return ids


def jpeg_tensor(data: bytes) -> Tensor:
    """JPEG bytes as the 1-D uint8 tensor the decoders take (a copy: torch refuses to wrap read-only bytes)."""
    return torch.frombuffer(bytearray(data), dtype=torch.uint8)


def decode_rgb(encoded: list[Tensor], device: torch.device | str) -> list[Tensor]:
    """JPEGs (1-D uint8 CPU tensors) as (3, H, W) uint8 RGB on ``device``: nvJPEG on CUDA, one call for them all;
    libjpeg-turbo on the CPU, pixel for pixel what OpenCV's decode gives.

    On CUDA the caller's stream is drained first: torchvision's decoder writes on a stream of its own that does not
    wait for the caller's, into memory the caching allocator may just have taken back from kernels still queued there
    (pytorch/vision#9606: corrupted pixels on an H100). Training syncs once a step anyway (the progress bar reads the
    loss), so this costs little overlap."""
    device = torch.device(device)
    if device.type == "cuda":
        torch.cuda.current_stream(device).synchronize()
    with warnings.catch_warnings():  # torchvision 0.29 deprecates its codecs for torchcodec, whose wheels each fit
        warnings.simplefilter("ignore", DeprecationWarning)  # one torch release only; ours follow torchvision's range
        return decode_jpeg(list(encoded), mode=ImageReadMode.RGB, device=device)


def decode_images(batch: Batch, device: torch.device | str) -> Batch:
    """``batch`` with its :data:`RGB_JPEG` images decoded into ``rgb`` on ``device`` (nvJPEG on CUDA, one call for the
    batch; libjpeg-turbo on the CPU); a batch without them is returned as it is. Every image must decode to the same
    size (the model's ``image_size``, which the loader checked against the cameras' calibration)."""
    if RGB_JPEG not in batch:
        return batch
    batch = dict(batch)
    encoded = batch.pop(RGB_JPEG)
    keys = batch.get("__key__", [str(i) for i in range(len(encoded))])
    try:
        images = decode_rgb(encoded, device)
    except RuntimeError as err:
        raise ValueError(f"a camera JPEG of the samples {keys} is not decodable: {err}") from None
    sizes = {tuple(image.shape[-2:]) for image in images}
    if len(sizes) > 1:
        found = ", ".join(f"{key}: {tuple(image.shape[-2:])}" for key, image in zip(keys, images, strict=True))
        raise ValueError(
            f"the batch's camera JPEGs decode to different sizes ({found}); each should be the model's image_size, as "
            "its meta.cameras calibration says: re-convert the samples whose JPEG and calibration disagree"
        )
    batch["rgb"] = torch.stack(images)
    return batch


def check_device_decode(encoded: Tensor, decoded: Tensor) -> float:
    """The mean absolute difference between ``decoded`` (a JPEG decoded on a device) and libjpeg-turbo's decode of
    ``encoded`` on the CPU; raises when it exceeds :data:`DEVICE_DECODE_TOLERANCE`, a broken device decoder."""
    reference = decode_rgb([encoded], "cpu")[0]
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
    :func:`~lead_s2r.data.transforms.rasterize_lidar` (the same float32 arithmetic, truncation as the floor inside
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
