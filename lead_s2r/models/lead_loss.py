"""LEAD's training computation: the loss terms of ``TFv6.compute_loss`` (commit 4489176), the Trainer's weight table,
its optimizer and its learning-rate schedule, in LEAD's contract (LEAD's target keys, frame and term names).

:func:`loss` is what LEAD's training step backpropagates; the term functions are pure tensor code our LightningModule
calls on our batches too (``lead_s2r.training.loss_table``), so LEAD's computation exists once. What LEAD does that an
independent implementation would likely miss, each kept on purpose (docs/models.md, "Training as LEAD trains"):

- depth labels are truncated to whole metres (``.long()``), and the depth term exists only with ``use_semantic``;
- BEV semantics: pixels outside an approximate camera frustum are ignored, yet still counted in the per-sample mean;
- CenterNet terms are normalised per sample (by that sample's peak count + float32 eps), size and offset also by 2;
- the radar term matches queries to label slots by the Hungarian algorithm (scipy) on the detached cost;
- the NAVSIM heading L1 is added into the waypoint term; the route term is L1 plus L1 of the last point;
- weights are normalised over LEAD's whole table, including zero weights and terms a configuration never produces
  (a NAVSIM LTFv6's seven terms each weigh 1/9). TFv5's own terms (``loss_tf``, ``loss_tfpp_speed``, ``loss_tfpp``)
  are missing from LEAD's table, so LEAD's Trainer fails on them; here they take the weight of the TFv6 term each
  stands for.

The optimizer is LEAD's ``initialize_optimizer``: AdamW with AMSGrad and weight decay on every parameter (one group,
biases and norms included), torch's betas and eps, no gradient clipping; its schedule: :func:`cosine_schedule`.
"""

import math
from collections.abc import Iterable, Mapping
from enum import IntEnum

import numpy as np
import torch
import torch.nn.functional as F
from scipy.optimize import linear_sum_assignment
from torch import Tensor, nn

from lead_s2r.models.lead_config import TARGET_SPEED_CLASSES, TRAINING_USED_LIDAR_STEPS, LeadConfig
from lead_s2r.models.lead_tfv6 import LeadTFv6

#: float32's machine epsilon, LEAD's CenterNet normaliser offset (``torch.finfo(torch_float_type).eps``).
FLOAT32_EPS = torch.finfo(torch.float32).eps
#: LEAD's radar matching and loss weights (``radar_regression_loss_weight``, ``radar_classification_loss_weight``).
RADAR_REGRESSION_WEIGHT, RADAR_CLASSIFICATION_WEIGHT = 5.0, 1.0
#: LEAD's CenterNet term names, without the source prefix.
CENTER_NET_TERMS = ("heatmap", "wh", "offset", "yaw_class", "yaw_res", "velocity")
#: TFv5's terms -> the TFv6 term whose weight each takes (LEAD's table has none for them).
TFV5_TERMS = {
    "loss_tf": "loss_spatio_temporal_waypoints",
    "loss_tfpp_speed": "loss_target_speed",
    "loss_tfpp": "loss_spatial_route",
}


class SourceDataset(IntEnum):
    """LEAD's ``SourceDataset`` codes: the per-sample ``source_dataset`` target every perception term masks by."""

    CARLA = 1
    NAVSIM = 2
    WAYMO_E2E_2025 = 3


def prefix(source: SourceDataset) -> str:
    """LEAD's term-name prefix of a source's perception terms (CARLA's have none)."""
    return "" if source == SourceDataset.CARLA else f"{source.name.lower()}_"


# --- weights ---------------------------------------------------------------------------------------------------------
def source_weights(config: LeadConfig, source: SourceDataset) -> dict[str, float]:
    """LEAD's ``detailed_loss_weights`` for one source, before normalisation (config_training.py:918-990)."""
    weights = {
        "loss_semantic": float(config.use_semantic),
        "loss_depth": 1e-5 if config.use_depth else 0.0,
        "loss_bev_semantic": float(config.use_bev_semantic),
        **{f"loss_center_net_{term}": float(config.detect_boxes) for term in CENTER_NET_TERMS},
        "radar_loss": float(bool(config.radar_detection)),
    }
    if source != SourceDataset.CARLA:
        weights.update(radar_loss=0.0, loss_semantic=0.0, loss_depth=0.0, loss_center_net_velocity=0.0)
    if config.LTF or TRAINING_USED_LIDAR_STEPS <= 1:
        weights["loss_center_net_velocity"] = 0.0
    planning = ("loss_spatio_temporal_waypoints", "loss_target_speed", "loss_spatial_route")
    prefixed = {f"{prefix(source)}{k}": v for k, v in weights.items()}
    return prefixed | dict.fromkeys(planning, float(config.use_planning_decoder))


def training_sources(config: LeadConfig) -> tuple[SourceDataset, ...]:
    """The sources LEAD's Trainer builds weights for, in its order."""
    used = (config.use_carla_data, config.use_navsim_data, config.use_waymo_e2e_data)
    return tuple(source for source, use in zip(SourceDataset, used, strict=True) if use)


def loss_weights(config: LeadConfig) -> dict[str, float]:
    """The Trainer's weight of every term (``schedule_loss_weights``): the sources' tables merged, over their sum."""
    table: dict[str, float] = {}
    for source in training_sources(config):
        table.update(source_weights(config, source))
    total = sum(table.values())
    normalised = {key: value / total for key, value in table.items()}
    return normalised | {tfv5: normalised[tfv6] for tfv5, tfv6 in TFV5_TERMS.items()}


# --- perception terms ------------------------------------------------------------------------------------------------
def source_mean(per_sample: Tensor, source_mask: Tensor) -> Tensor:
    """Mean of per-sample values over the samples of one source (LEAD's masking of every perception term)."""
    mask = source_mask.to(per_sample.dtype)
    return (per_sample * mask).sum() / mask.sum().clamp(min=1)


def semantic_loss(logits: Tensor, label: Tensor, source_mask: Tensor) -> Tensor:
    """Image-space semantic cross-entropy, mean per sample (a -1 pixel adds 0 yet counts; LEAD's labels have none)."""
    per_pixel = F.cross_entropy(logits.float(), label.long(), reduction="none", ignore_index=-1)
    return source_mean(per_pixel.mean(dim=(1, 2)), source_mask)


def depth_loss(depth: Tensor, label: Tensor, source_mask: Tensor) -> Tensor:
    """Depth L1 per pixel against the label truncated to whole metres (LEAD casts it to int64), mean per sample."""
    per_pixel = F.l1_loss(depth.float(), label.long().float(), reduction="none")
    return source_mean(per_pixel.mean(dim=(1, 2)), source_mask)


def visible_bev_pixels(config: LeadConfig) -> Tensor:
    """(H, W) float mask of LEAD's BEV raster pixels inside its approximate camera frustum (``BEVDecoder``): a wedge
    of half-angle (cameras x 60 + 5) / 2 degrees around +x from the ego's pixel (row H // 2); all pixels with three or
    more cameras."""
    h, w = config.lidar_height_pixel, config.lidar_width_pixel
    if config.num_used_cameras >= 3:
        return torch.ones(h, w)
    half_angle = math.radians((config.num_used_cameras * 60 + 5) / 2)
    rows, cols = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(w, dtype=np.float64), indexing="ij")
    angle = np.arctan2(rows - h // 2, cols + config.min_x_meter * config.pixels_per_meter)
    return torch.from_numpy(np.abs(angle) <= half_angle).float()


def bev_semantic_loss(logits: Tensor, label: Tensor, visible: Tensor, source_mask: Tensor) -> Tensor:
    """BEV cross-entropy ignoring invisible pixels, which still count in each sample's mean over all pixels."""
    visible = visible.to(logits.device)
    masked = (label.long() * visible + (visible - 1)).long()  # LEAD's mask_label: invisible -> -1
    per_pixel = F.cross_entropy(logits.float(), masked, reduction="none", ignore_index=-1)
    return source_mean(per_pixel.mean(dim=(1, 2)), source_mask)


def gaussian_focal_loss(probability: Tensor, target: Tensor, alpha: float = 2.0, gamma: float = 4.0) -> Tensor:
    """Per-cell penalty-reduced focal loss on heatmap probabilities (mmdetection's, as LEAD adapted it): positives
    are cells exactly 1, every cell counts as a negative weighted by (1 - target)^gamma."""
    probability, target = probability.float(), target.float()
    eps = 1e-12
    positive = -(probability + eps).log() * (1 - probability).pow(alpha) * target.eq(1)
    negative = -(1 - probability + eps).log() * probability.pow(alpha) * (1 - target).pow(gamma)
    return positive + negative


def center_net_losses(
    pred: Mapping[str, Tensor], target: Mapping[str, Tensor], source_mask: Tensor, velocity: bool = True
) -> dict[str, Tensor]:
    """LEAD's CenterNet terms (``loss_center_net_<term>``, unprefixed) for one head.

    ``pred`` holds LEAD's head outputs (``center_heatmap_pred``: probabilities), ``target`` LEAD's labels without the
    source prefix (``center_net_pixel_weight`` (B, 2, H, W), ``center_net_avg_factor`` (B,)). Without ``velocity``
    the velocity term is LEAD's zeros(1).
    """
    weight = target["center_net_pixel_weight"].float()
    count = target["center_net_avg_factor"].float() + FLOAT32_EPS

    def normalised(per_sample: Tensor, divisor: int = 1) -> Tensor:
        return source_mean(per_sample / (count * divisor), source_mask)

    def weighted_l1(name: str, label: str, channels: slice) -> Tensor:
        l1 = F.l1_loss(pred[name].float(), target[label].float(), reduction="none") * weight[:, channels]
        return l1.sum(dim=(1, 2, 3))

    heatmap = gaussian_focal_loss(pred["center_heatmap_pred"], target["center_net_heatmap"]).sum(dim=(1, 2, 3))
    size_channels = pred["wh_pred"].shape[1]
    yaw_class = F.cross_entropy(pred["yaw_class_pred"].float(), target["center_net_yaw_class"].long(), reduction="none")
    yaw_res = F.smooth_l1_loss(pred["yaw_res_pred"].float(), target["center_net_yaw_res"].float(), reduction="none")
    losses = {
        "loss_center_net_heatmap": normalised(heatmap),
        "loss_center_net_wh": normalised(weighted_l1("wh_pred", "center_net_wh", slice(None)), size_channels),
        "loss_center_net_offset": normalised(
            weighted_l1("offset_pred", "center_net_offset", slice(None)), size_channels
        ),
        "loss_center_net_yaw_class": normalised((yaw_class * weight[:, 0]).sum(dim=(1, 2))),
        "loss_center_net_yaw_res": normalised((yaw_res * weight[:, 0:1]).sum(dim=(1, 2, 3))),
        "loss_center_net_velocity": torch.zeros(1, device=heatmap.device),
    }
    if velocity:
        velocity_l1 = weighted_l1("velocity_pred", "center_net_velocity", slice(0, 1))
        losses["loss_center_net_velocity"] = normalised(velocity_l1)
    return losses


def radar_feature_scale(config: LeadConfig) -> tuple[float, float, float]:
    """What LEAD's radar terms divide (x, y, v) by: the BEV's x and y extents in metres and the maximum speed."""
    return (config.max_x_meter - config.min_x_meter, config.max_y_meter - config.min_y_meter, config.max_speed)


def hungarian_matches(cost: Tensor) -> tuple[Tensor, Tensor]:
    """Per sample, the (query, slot) pairs of least total detached cost, each (B, matches)."""
    pairs = [linear_sum_assignment(sample.detach().cpu().double().numpy()) for sample in cost]
    queries, slots = (torch.as_tensor(np.stack(side), device=cost.device) for side in zip(*pairs, strict=True))
    return queries, slots


def radar_loss(pred: Tensor, detections: Tensor, scale: tuple[float, float, float]) -> Tensor:
    """LEAD's radar detection term: (B, Q, 4) predictions (x, y, v, validity logit) against (B, Q, 4) label slots
    (x, y, v, valid), matched one to one by 5 x scaled L1 (valid slots only) + 1 x BCE; the loss is the same mix of
    the matched L1 (per valid slot) and the BCE (over all slots), averaged over samples."""
    state, logit = pred[..., :3].float(), pred[..., 3:].float()
    label_state, valid = detections[..., :3].float(), detections[..., 3:].float()
    known = (~label_state.isnan()).float()  # our extension: a speed the data does not know (NaN) adds nothing
    label_state = label_state.nan_to_num()
    norm = torch.tensor(scale, device=state.device, dtype=state.dtype)
    l1_cost = (((state[:, :, None] - label_state[:, None]) / norm).abs() * known[:, None]).sum(-1)
    l1_cost = l1_cost * valid[:, None, :, 0]
    bce_cost = F.binary_cross_entropy_with_logits(
        logit[:, :, None].expand(-1, -1, valid.shape[1], -1),
        valid[:, None].expand(-1, logit.shape[1], -1, -1),
        reduction="none",
    )[..., 0]
    queries, slots = hungarian_matches(RADAR_REGRESSION_WEIGHT * l1_cost + RADAR_CLASSIFICATION_WEIGHT * bce_cost)
    rows = torch.arange(len(state), device=state.device)[:, None]
    matched_valid = valid[rows, slots][..., 0]
    l1 = (((state[rows, queries] - label_state[rows, slots]) / norm).abs() * known[rows, slots]).sum(-1) * matched_valid
    l1 = l1.sum(-1) / matched_valid.sum(-1).clamp(min=1)
    bce = F.binary_cross_entropy_with_logits(logit[rows, queries], valid[rows, slots], reduction="none")
    return (RADAR_REGRESSION_WEIGHT * l1 + RADAR_CLASSIFICATION_WEIGHT * bce[..., 0].mean(-1)).mean()


# --- planning terms --------------------------------------------------------------------------------------------------
def two_hot(speed: Tensor, brake: Tensor, classes: Iterable[float] | Tensor = TARGET_SPEED_CLASSES) -> Tensor:
    """(B,) target speeds -> (B, C) probabilities on the two neighbouring classes (linear split); a braking sample is
    class 0 and a speed at or above the last class is the last class (LEAD's ``encode_two_hot``)."""
    speed = speed.float()
    bins = torch.as_tensor(classes, dtype=speed.dtype, device=speed.device)
    clamped = speed.clamp(bins[0], bins[-1])
    upper = torch.searchsorted(bins, clamped, right=False).clamp(1, len(bins) - 1)
    lower_value, upper_value = bins[upper - 1], bins[upper]
    upper_weight = (clamped - lower_value) / (upper_value - lower_value)
    lower_weight = (upper_value - clamped) / (upper_value - lower_value)
    encoded = torch.zeros(len(speed), len(bins), dtype=speed.dtype, device=speed.device)
    encoded.scatter_(1, (upper - 1)[:, None], lower_weight[:, None])
    encoded.scatter_add_(1, upper[:, None], upper_weight[:, None])
    encoded[speed >= bins[-1]] = F.one_hot(torch.tensor(len(bins) - 1), len(bins)).to(encoded)
    encoded[brake.bool()] = F.one_hot(torch.tensor(0), len(bins)).to(encoded)
    return encoded


def target_speed_loss(logits: Tensor, speed: Tensor, brake: Tensor) -> Tensor:
    """Cross-entropy of target-speed logits against the two-hot label."""
    return F.cross_entropy(logits.float(), two_hot(speed, brake).to(logits.device))


def route_loss(route: Tensor, label: Tensor, last_point: bool = True) -> Tensor:
    """Route L1 over every checkpoint, plus (TFv6, not TFv5) L1 of the last one."""
    loss = F.l1_loss(route.float(), label.float())
    if last_point:
        loss = loss + F.l1_loss(route[:, -1].float(), label[:, -1].float())
    return loss


def planning_losses(
    config: LeadConfig, outputs: Mapping[str, Tensor], targets: Mapping[str, Tensor]
) -> dict[str, Tensor]:
    """TFv6's planner terms (``PlanningDecoder.compute_loss``) or TFv5's (``TFv5PlanningDecoder.compute_loss``)."""
    waypoints = targets["future_waypoints"].float()[:, : config.num_way_points_prediction]
    if config.use_tfv5_planning_decoder:
        return {
            "loss_tf": F.l1_loss(outputs["pred_future_waypoints"].float(), waypoints),
            "loss_tfpp_speed": target_speed_loss(
                outputs["pred_target_speed_distribution"], targets["target_speed"], targets["brake"]
            ),
            "loss_tfpp": route_loss(outputs["pred_route"], targets["route"], last_point=False),
        }
    losses = {}
    if config.predict_temporal_spatial_waypoints:
        losses["loss_spatio_temporal_waypoints"] = F.l1_loss(outputs["pred_future_waypoints"].float(), waypoints)
        if config.use_navsim_data:
            headings = F.l1_loss(outputs["pred_headings"].float(), targets["future_yaws"].float())
            losses["loss_spatio_temporal_waypoints"] = losses["loss_spatio_temporal_waypoints"] + headings
    if config.predict_target_speed:
        losses["loss_target_speed"] = target_speed_loss(
            outputs["pred_target_speed_distribution"], targets["target_speed"], targets["brake"]
        )
    if config.predict_spatial_path:
        losses["loss_spatial_route"] = route_loss(outputs["pred_route"], targets["route"])
    return losses


# --- the whole step --------------------------------------------------------------------------------------------------
def compute_losses(
    config: LeadConfig, outputs: Mapping[str, Tensor], targets: Mapping[str, Tensor]
) -> dict[str, Tensor]:
    """Every term ``TFv6.compute_loss`` returns, in its order, for LEAD's outputs and targets (a perception term is
    absent when no sample of its source is in the batch, as in LEAD)."""
    c = config
    device = next(iter(outputs.values())).device
    source_dataset = targets["source_dataset"].to(device).long()
    losses: dict[str, Tensor] = {}
    carla = source_dataset == SourceDataset.CARLA
    if c.use_carla_data and c.use_semantic and carla.any():
        losses["loss_semantic"] = semantic_loss(outputs["pred_semantic"], targets["semantic"].to(device), carla)
        if c.use_depth:
            losses["loss_depth"] = depth_loss(outputs["pred_depth"], targets["depth"].to(device), carla)
    heads = [(SourceDataset.CARLA, "", c.use_carla_data), (SourceDataset.NAVSIM, "_navsim", c.use_navsim_data)]
    if c.use_bev_semantic:
        visible = visible_bev_pixels(c).to(device)
        for source, suffix, used in heads:
            mask = source_dataset == source
            if used and mask.any():
                label = targets[f"{prefix(source)}bev_semantic"].to(device)
                key = f"{prefix(source)}loss_bev_semantic"
                losses[key] = bev_semantic_loss(outputs[f"pred_bev_semantic{suffix}"], label, visible, mask)
    if c.detect_boxes:
        for source, suffix, used in heads:
            mask = source_dataset == source
            if used and mask.any():
                pred = _strip(outputs, f"pred_bounding_box{suffix}.")
                label = _strip(targets, f"{prefix(source)}center_net_", keep="center_net_")
                terms = center_net_losses(pred, label, mask, velocity=TRAINING_USED_LIDAR_STEPS > 1)
                losses.update({f"{prefix(source)}{k}": v for k, v in terms.items()})
    if c.has_radar_detector:
        detections = targets["radar_detections"].to(device)
        losses["radar_loss"] = radar_loss(outputs["pred_radar_predictions"], detections, radar_feature_scale(c))
    if c.use_planning_decoder:
        losses.update(planning_losses(c, outputs, {k: v.to(device) for k, v in targets.items()}))
    return losses


def _strip(values: Mapping[str, Tensor], start: str, keep: str = "") -> dict[str, Tensor]:
    """The entries whose key starts with ``start``, keyed by ``keep`` + the rest of the key."""
    return {keep + key[len(start) :]: value for key, value in values.items() if key.startswith(start)}


def weighted_total(losses: Mapping[str, Tensor], weights: Mapping[str, float]) -> Tensor:
    """The Trainer's sum, zeros(1) first, in the terms' order; a term the table lacks is an error, as in LEAD."""
    missing = [key for key in losses if key not in weights]
    if missing:
        raise KeyError(f"LEAD's weight table has no entry for {missing}")
    device = next(iter(losses.values())).device
    total = torch.zeros(1, device=device)
    for key, value in losses.items():
        total = total + weights[key] * value.reshape(1)
    return total


def network_of(model: nn.Module) -> LeadTFv6:
    """The LEAD network of ``model``: itself, or a :class:`~lead_s2r.models.lead_driver.LeadDriver`'s ``network``."""
    network = getattr(model, "network", model)
    if not isinstance(network, LeadTFv6):
        raise TypeError(f"expected a LEAD network (LeadTFv6 or LeadDriver), got {type(model).__name__}")
    return network


def training_layout(model: nn.Module) -> nn.Module:
    """``model`` with its weights in channels-last memory format, in place, as LEAD's ``initialize_model`` trains it.
    The layout changes the convolutions' summation order: with BatchNorm on batch statistics (train mode) the
    rounding differences of the contiguous layout grow to 1e-4 of a gradient, against 1e-6 in LEAD's layout."""
    return model.to(memory_format=torch.channels_last)


def loss(model: nn.Module, inputs: Mapping[str, Tensor], targets: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """LEAD's training loss for one batch in LEAD's contract: the forward on ``{**inputs, **targets}`` in the model's
    current mode, every term under LEAD's name, and ``total`` (shape (1,)), the weighted sum LEAD backpropagates."""
    network = training_layout(network_of(model))
    outputs = network({**inputs, **targets})
    losses = compute_losses(network.config, outputs, targets)
    return {**losses, "total": weighted_total(losses, loss_weights(network.config))}


# --- optimizer and schedule ------------------------------------------------------------------------------------------
def adamw(
    parameters: Iterable[nn.Parameter],
    lr: float = 3e-4,
    weight_decay: float = 0.01,
    betas: tuple[float, float] = (0.9, 0.999),
    amsgrad: bool = True,
) -> torch.optim.AdamW:
    """LEAD's optimizer: one AdamW group, weight decay on every parameter, AMSGrad, the fused kernel LEAD asks for
    (torch's for-each kernel where the parameters' device has no fused one)."""
    parameters = list(parameters)
    fused = all(p.device.type in ("cpu", "cuda") and p.dtype.is_floating_point for p in parameters)
    return torch.optim.AdamW(
        parameters, lr=lr, betas=betas, weight_decay=weight_decay, amsgrad=amsgrad, fused=fused or None
    )


def optimizer(model: nn.Module, config: LeadConfig | Mapping | None = None) -> torch.optim.AdamW:
    """LEAD's optimizer for ``model`` with the settings of ``config`` (a :class:`LeadConfig` or a config.json dict;
    default: the model's): ``lr`` and ``weight_decay`` (3e-4, 0.01 unless the file sets them)."""
    config = network_of(model).config if config is None else _config(config)
    return adamw(model.parameters(), lr=config.lr, weight_decay=config.weight_decay)


def cosine_schedule(
    optimizer: torch.optim.Optimizer, steps_per_epoch: int, epochs: int, restarts: bool, skipped_steps: int = 0
) -> torch.optim.lr_scheduler.LRScheduler:
    """LEAD's schedule, stepped after every optimizer step: a cosine restarting after 1, 2, 4 ... epochs, or one
    cosine over ``epochs`` epochs, less ``skipped_steps`` spent before it (ours: a warm-up; LEAD has none)."""
    schedules = torch.optim.lr_scheduler
    if restarts:
        return schedules.CosineAnnealingWarmRestarts(optimizer, T_0=steps_per_epoch, T_mult=2)
    return schedules.CosineAnnealingLR(optimizer, T_max=max(1, steps_per_epoch * epochs - skipped_steps))


def scheduler(
    optimizer: torch.optim.Optimizer, config: LeadConfig | Mapping, steps_per_epoch: int
) -> torch.optim.lr_scheduler.LRScheduler:
    """LEAD's schedule for a config (``use_cosine_annealing_with_restarts``: off for WOD-E2E; ``epochs``)."""
    config = _config(config)
    return cosine_schedule(optimizer, steps_per_epoch, config.epochs, config.use_cosine_annealing_with_restarts)


def _config(config: LeadConfig | Mapping) -> LeadConfig:
    return config if isinstance(config, LeadConfig) else LeadConfig.from_json(dict(config))
