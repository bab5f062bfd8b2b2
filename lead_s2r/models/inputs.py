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

On a GPU the loader may leave two inputs raw, ``rgb_jpeg`` (with ``rgb_layout``) instead of ``rgb`` and ``lidar_points``
instead of ``lidar_bev``, which :mod:`lead_s2r.data.device_inputs` builds on the training device before the batch moves.
"""

from typing import TypedDict

import torch
import torch.nn.functional as F
from torch import Tensor

#: LiDAR hits per BEV cell at which the raster saturates (LEAD's ``rasterize_lidar``: clip at 5, scale to [0, 1]).
LIDAR_HITS_MAX = 5
#: Class id of "no label" in a uint8 class map (no class table uses it: they stop far below 255).
IGNORE_CLASS = 255


class Batch(TypedDict, total=False):
    """Inputs and targets of one per-source batch (B samples). Keys a source does not have are left out."""

    __key__: list[str]  # sample keys, for predictions
    __dataset__: list[str]  # each sample's meta.dataset, for predictions and per-dataset scoring
    # --- inputs
    rgb: Tensor  # (B, 3, H, W) uint8 (or float in [0, 255]), RGB order; normalised inside the model
    rgb_jpeg: list[list[Tensor]]  # instead of rgb: each sample's camera JPEGs (1-D uint8, CPU), see data.device_inputs
    rgb_layout: list  # with rgb_jpeg: each sample's data.camera_layout.CameraLayout (the device lays the cameras out)
    lidar_bev: Tensor  # (B, C, Hb, Wb) uint8 hits per cell, 0..LIDAR_HITS_MAX (or float in [0, 1]) (TFv6 only)
    lidar_points: list[Tensor]  # instead of lidar_bev: each sample's (N, 2) x, y, see lead_s2r.data.device_inputs
    speed: Tensor  # (B,) m/s
    acceleration: Tensor  # (B, 2) m/s^2, [ax, ay] in the ego frame
    command: Tensor  # (B,) int64 in the 4-way {UNKNOWN, LEFT, STRAIGHT, RIGHT} (schema.command4)
    command_full: Tensor  # (B,) int64 schema.Command (all 7 values), for LEAD's 6-way CARLA command
    origin_x: Tensor  # (B,) metres the sample's origin moved forward from the rear axle (LEAD's CARLA frame)
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
    brake: Tensor  # (B,) bool: the expert brakes (LEAD's target-speed label is then its 0 m/s class)
    # --- perception targets
    bev_semantic: Tensor  # (B, Hs, Ws) uint8 class ids over the BEV grid, IGNORE_CLASS = ignore (or signed, -1)
    lead_box_heatmap: Tensor  # (B, C, h, w) LEAD's CenterNet encoding (lead_s2r.data.lead_centernet), -1 = no label
    lead_box_size: Tensor  # (B, 2, h, w) half length, half width in cells, at the weighted cells
    lead_box_offset: Tensor  # (B, 2, h, w) sub-cell centre offset along x, y
    lead_box_yaw_class: Tensor  # (B, h, w) uint8 yaw bin
    lead_box_yaw_residual: Tensor  # (B, h, w) radians from the bin centre
    lead_box_velocity: Tensor  # (B, h, w) m/s
    lead_box_weight: Tensor  # (B, h, w) bool: the cells holding a box centre
    lead_box_count: Tensor  # (B,) heatmap peaks (at least 1), the per-sample normaliser
    depth: Tensor  # (B, Hd, Wd) float32 metres, 0 = no label; (Hd, Wd) = (H, W) or smaller (see below)
    semantic: Tensor  # (B, Hd, Wd) uint8 perspective class ids, IGNORE_CLASS = ignore (or signed, -1)
    radar_targets: Tensor  # (B, R, 3) x, y, speed of objects seen by radar
    radar_targets_valid: Tensor  # (B, R)


#: Loss terms by group: the planner's outputs, and the perception heads' (``supervise:`` names these groups).
PLANNING_TASKS = frozenset({"waypoints", "headings", "route", "target_speed"})
PERCEPTION_TASKS = frozenset({"bev_semantic", "lead_boxes", "depth", "semantic", "radar"})


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
    """A class map as int64 ids, -1 where there is no label (a uint8 map marks it :data:`IGNORE_CLASS`)."""
    ids = labels.long()
    if labels.dtype == torch.uint8:
        ids = ids.masked_fill(labels == IGNORE_CLASS, -1)
    return ids
