"""Inputs the loader leaves raw on a GPU run (``DriveDataModule(inputs_on_device=...)``) and the training device
builds before the batch moves: camera JPEGs decoded (``rgb_jpeg`` -> ``rgb``) and LiDAR points rasterised
(``lidar_points`` -> ``lidar_bev``).

Why: the loader's CPU per sample sets how many cores each GPU needs (docs/benchmarks.md, "Training loader"). The
1152x384 CARLA mosaic costs it 0.7-1.5 ms a sample to decode and 0.2 ms to stack; a LEAD frame's 60,000 LiDAR
points 0.6 ms to rasterise. Left raw, the image crosses to the device as 12-200 KB of JPEG instead of 1.3 MB of
pixels, and nvJPEG and one ``bincount`` per batch do the work there. Only a camera JPEG that already is the model's
image (one camera at ``image_size``: nothing to crop, stitch or scale) goes encoded; other rigs are laid out in the
loader.

The raster is bit for bit the loader's (:func:`~lead_s2r.data.lidar.rasterize_lidar`: the same float32
arithmetic). On the CPU the decoder is libjpeg-turbo, pixel for pixel OpenCV's decode; nvJPEG's pixels may differ
by a level or two (its own IDCT and chroma upsampling), and the first image a run decodes on a GPU is held to the
CPU's decode (:func:`check_device_decode`). torchvision's CUDA decoder writes on a stream of its own that does not
wait for the caller's (pytorch/vision#9606: corrupted pixels on an H100 when the caching allocator hands it memory
that queued kernels still read), so :func:`decode_rgb` drains the caller's stream first.
"""

import warnings

import torch
from torch import Tensor
from torchvision.io import ImageReadMode, decode_jpeg

from lead_s2r.models.config import BEVGrid
from lead_s2r.models.inputs import LIDAR_HITS_MAX, Batch

#: Batch key of input images left JPEG-encoded by the loader: a list of 1-D uint8 CPU tensors (:func:`decode_images`).
RGB_JPEG = "rgb_jpeg"
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
    libjpeg-turbo on the CPU, pixel for pixel what OpenCV's decode gives. On CUDA the caller's stream is drained
    first (see the module docstring); training syncs once a step anyway (the progress bar reads the loss), so this
    costs little overlap."""
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
