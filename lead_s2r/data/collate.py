"""Per-sample tensors -> one batch: labels only some samples carry filled where missing (and masked by construction),
perspective labels of different rigs brought onto one grid, the inputs left for the device kept as lists."""

from typing import Any

import torch
from torch.utils.data import default_collate

from lead_s2r.data.device_inputs import LIDAR_POINTS, RGB_JPEG, RGB_LAYOUT, decode_images
from lead_s2r.models.inputs import IGNORE_CLASS, on_image_grid

#: Fill value of a label a sample lacks: the loss ignores it (masks are False, depth 0 means "no label").
IGNORE_VALUE = {"bev_semantic": IGNORE_CLASS, "semantic": IGNORE_CLASS, "lead_box_heatmap": -1}
#: Labels on the input image's pixel grid, possibly left at their stored (smaller) size: see :func:`on_image_grid`.
IMAGE_ALIGNED = frozenset({"depth", "semantic"})


def collate(samples: list[dict[str, Any]]) -> dict[str, Any]:
    """Stack per-sample tensors into a batch; a label only some samples carry is filled (:data:`IGNORE_VALUE`).

    Identity entries (``__key__``, ``__dataset__``) and the inputs left for the device (:data:`RGB_JPEG` with
    :data:`RGB_LAYOUT`, :data:`LIDAR_POINTS`) become lists; where only some samples' rigs let their JPEGs go encoded,
    those are decoded and laid out here, as the device would. Perspective labels left at their stored size by rigs of
    different sizes (one source, several camera rigs) are brought onto the image's grid here, as the loss would. In a
    dataloader worker each tensor is stacked straight into shared memory (torch's ``default_collate``), not into private
    memory that the worker then copies into shared memory to send the batch."""
    if any(RGB_JPEG in sample for sample in samples) and not all(RGB_JPEG in sample for sample in samples):
        samples = [_decoded(sample) for sample in samples]
    names = set().union(*samples)
    listed = {name for name in names if name.startswith("__")} | ({RGB_JPEG, RGB_LAYOUT, LIDAR_POINTS} & names)
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
        if key == "rgb":
            # (3, H, W) views of the (H, W, 3) pixels decoders write: stacked as (B, H, W, 3), one plain copy, and
            # handed on as a channels-last (B, 3, H, W) view (not a per-sample planar copy)
            batch[key] = default_collate([value.permute(1, 2, 0) for value in values]).permute(0, 3, 1, 2)
        else:
            batch[key] = default_collate(values)
    return batch


def _decoded(sample: dict[str, Any]) -> dict[str, Any]:
    """``sample`` with JPEGs left for the device decoded and laid out into ``rgb`` here."""
    if RGB_JPEG not in sample:
        return sample
    sample = dict(sample)
    one = decode_images({RGB_JPEG: [sample.pop(RGB_JPEG)], RGB_LAYOUT: [sample.pop(RGB_LAYOUT)]}, "cpu")
    sample["rgb"] = one["rgb"][0]
    return sample


def batch_image_size(samples: list[dict[str, Any]]) -> tuple[int, int]:
    """The (H, W) of the input image of a batch's samples (they share the model's ``image_size``)."""
    sample = next((sample for sample in samples if "rgb" in sample or RGB_JPEG in sample), None)
    if sample is None:
        raise KeyError("perspective labels (depth, semantic) need the samples' 'rgb' to know the image grid")
    return tuple(_decoded(sample)["rgb"].shape[-2:])
