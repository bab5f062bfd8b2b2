"""Loss terms of one source's batch, one function per task (keyed by task in :mod:`lead_s2r.training.loss_table`).

LEAD's terms (perspective semantics and depth, BEV semantics, CenterNet boxes, radar detection, the two-hot target
speed) are LEAD's own definitions in :mod:`lead_s2r.models.lead_loss`; the functions here only carry our batch (our
names, the ISO frame, label masks) into them. Waypoints, headings and route are masked means, equal to LEAD's plain
means where every pose is labelled. Predictions are cast to float32, so the terms are stable under bf16 autocast.
"""

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from lead_s2r.models import lead_loss
from lead_s2r.models.inputs import Batch, class_ids


def masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean of ``values`` over ``mask`` (broadcast from the left); zero, still in the graph, when nothing is valid."""
    mask = mask.to(values.dtype)
    while mask.dim() < values.dim():
        mask = mask.unsqueeze(-1)
    mask = mask.expand_as(values)
    return (values * mask).sum() / mask.sum().clamp(min=1.0)


def valid_mask(batch: Batch, key: str, like: Tensor) -> Tensor:
    """The (B, T) label mask ``<key>_valid`` of ``batch``; every entry valid where the batch has none."""
    return batch.get(f"{key}_valid", torch.ones(like.shape[:2], dtype=torch.bool, device=like.device))


def waypoint_loss(pred: dict[str, Tensor], batch: Batch) -> Tensor:
    """L1 over valid waypoints."""
    return masked_mean(
        (pred["waypoints"].float() - batch["waypoints"]).abs(), valid_mask(batch, "waypoints", batch["waypoints"])
    )


def heading_loss(pred: dict[str, Tensor], batch: Batch) -> Tensor:
    """L1 against the target headings unwrapped along the horizon (LEAD's plain L1, continuous through +-pi).

    The decoders' headings are cumulative sums, continuous from the current heading 0, so the target is made
    continuous too. A wrapped error instead lets each pose settle on either side of +-pi: trained on synthetic NAVSIM,
    the cumulative outputs then spun through 2 pi within one trajectory (0.3, 1.7, 4.2, 5.8, 6.5 rad on a straight
    road) at no cost in the loss, and the scorer's tracker followed the spin. Padded poses come last, so they do
    not shift the valid ones."""
    target = batch["headings"].float()
    steps = torch.diff(target, dim=1, prepend=torch.zeros_like(target[:, :1]))
    unwrapped = torch.cumsum(torch.remainder(steps + math.pi, 2 * math.pi) - math.pi, dim=1)
    return masked_mean((pred["headings"].float() - unwrapped).abs(), valid_mask(batch, "headings", target))


def route_loss(pred: dict[str, Tensor], batch: Batch) -> Tensor:
    """L1 over the route checkpoints plus L1 of the last valid one (ADE + FDE, as LEAD)."""
    target, route = batch["route"], pred["route"].float()
    valid = valid_mask(batch, "route", target)
    err = (route - target).abs()
    last = valid.long().cumsum(1).argmax(1)  # index of the last valid checkpoint
    rows = torch.arange(len(target), device=target.device)
    return masked_mean(err, valid) + masked_mean(err[rows, last], valid.any(1))


def target_speed_loss(pred: dict[str, Tensor], batch: Batch, classes: Tensor) -> Tensor:
    """Cross-entropy against LEAD's two-hot target speed (a braking sample is class 0), over labelled samples."""
    speed = batch["target_speed"]
    brake = batch.get("brake", torch.zeros_like(speed, dtype=torch.bool))
    target = lead_loss.two_hot(speed, brake, classes)
    ce = F.cross_entropy(pred["target_speed_logits"].float(), target, reduction="none")
    valid = batch.get("target_speed_valid", torch.ones_like(ce, dtype=torch.bool))
    return masked_mean(ce, valid)


def _resize_logits(logits: Tensor, size: tuple[int, int]) -> Tensor:
    if tuple(logits.shape[-2:]) == tuple(size):
        return logits.float()
    return F.interpolate(logits.float(), size=size, mode="bilinear", align_corners=False)


def lead_box_loss(pred: dict[str, Tensor], batch: Batch, velocity: bool) -> Tensor:
    """LEAD's CenterNet terms (:func:`~lead_s2r.models.lead_loss.center_net_losses`) on LEAD-encoded targets
    (``lead_s2r.data.lead_centernet``), summed: they all weigh the same in LEAD's table. The speed term only with
    ``velocity`` and a speed label (CARLA's; LEAD weighs NAVSIM's and LTF's 0), left out where the speed is unknown
    (NaN). A sample without boxes carries the collate filler (a heatmap of -1) and is left out, as LEAD leaves out
    another source's samples."""
    heatmap = batch["lead_box_heatmap"].float()
    labelled = (heatmap >= 0).flatten(1).all(dim=1)
    head = {
        "center_heatmap_pred": pred["box_heatmap"].float().sigmoid(),
        "wh_pred": pred["box_size"],
        "offset_pred": pred["box_offset"],
        "yaw_class_pred": pred["box_yaw_class"],
        "yaw_res_pred": pred["box_yaw_residual"],
    }
    weight = batch["lead_box_weight"].float()[:, None]
    target = {
        "center_net_heatmap": heatmap,
        "center_net_wh": batch["lead_box_size"],
        "center_net_offset": batch["lead_box_offset"],
        "center_net_yaw_class": batch["lead_box_yaw_class"],
        "center_net_yaw_res": batch["lead_box_yaw_residual"][:, None],
        "center_net_pixel_weight": torch.cat([weight, weight], dim=1),
        "center_net_avg_factor": batch["lead_box_count"],
    }
    velocity = velocity and "lead_box_velocity" in batch
    if velocity:
        head["velocity_pred"] = pred["box_velocity"]
        label = batch["lead_box_velocity"][:, None]
        # a box of unknown speed (NaN: its source has no velocity) is labelled with the prediction: no loss, no
        # gradient, and LEAD's normaliser (the box count) unchanged
        target["center_net_velocity"] = torch.where(label.isnan(), pred["box_velocity"].detach().to(label.dtype), label)
    terms = lead_loss.center_net_losses(head, target, labelled, velocity=velocity)
    if not velocity:
        del terms["loss_center_net_velocity"]
    return sum(terms.values())


def radar_slots(targets: Tensor, valid: Tensor, queries: int) -> Tensor:
    """Our radar targets (B, R, 3) and mask -> LEAD's (B, queries, 4) label slots (x, y, v, valid): labelled rows
    first, in their order, then padding, cut or padded to one slot per query (LEAD's loader pads to the query count)."""
    order = torch.sort((~valid.bool()).to(torch.uint8), dim=1, stable=True).indices
    slots = torch.cat([targets.float(), valid.float()[..., None]], dim=-1)
    slots = slots.gather(1, order[..., None].expand(-1, -1, 4))[:, :queries]
    return F.pad(slots, (0, 0, 0, queries - slots.shape[1]))


def radar_loss(pred: dict[str, Tensor], batch: Batch, scale: tuple[float, float, float]) -> Tensor:
    """LEAD's radar detection term (:func:`~lead_s2r.models.lead_loss.radar_loss`: Hungarian matching of queries to
    label slots, 5 x scaled L1 of matched (x, y, speed) per labelled slot + BCE of validity, mean over samples)."""
    xyv = torch.cat([pred["radar_xy"], pred["radar_speed"][..., None], pred["radar_logit"][..., None]], dim=-1)
    slots = radar_slots(batch["radar_targets"], batch["radar_targets_valid"], xyv.shape[1])
    return lead_loss.radar_loss(xyv, slots.to(xyv.device), scale)


def labelled_samples(ids: Tensor) -> Tensor:
    """(B,) whether a sample's class map holds any label (a sample without one is left out, as another source's)."""
    return (ids >= 0).flatten(1).any(dim=1)


def lead_bev_semantic_loss(logits: Tensor, labels: Tensor, visible: Tensor) -> Tensor:
    """LEAD's BEV term (:func:`~lead_s2r.models.lead_loss.bev_semantic_loss`): pixels outside ``visible`` (LEAD's
    camera frustum, on our grid) or without a label are ignored yet counted in each sample's mean."""
    ids = class_ids(labels)
    return lead_loss.bev_semantic_loss(logits, ids, visible, labelled_samples(ids))


def lead_semantic_loss(logits: Tensor, labels: Tensor) -> Tensor:
    """LEAD's perspective semantic term, mean over every pixel of each labelled sample (unlabelled pixels add 0)."""
    ids = class_ids(labels)
    return lead_loss.semantic_loss(_resize_logits(logits, tuple(ids.shape[-2:])), ids, labelled_samples(ids))


def lead_depth_loss(pred: Tensor, depth: Tensor) -> Tensor:
    """LEAD's depth term: L1 against the depth truncated to whole metres, mean over every pixel of each sample."""
    pred = _resize_logits(pred[:, None], tuple(depth.shape[-2:]))[:, 0]
    return lead_loss.depth_loss(pred, depth, torch.ones(len(depth), dtype=torch.bool, device=depth.device))
