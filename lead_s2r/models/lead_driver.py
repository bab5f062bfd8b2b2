"""LEAD's network with the interface our LightningModule trains and predicts with (``tasks``, ``grid``,
``forward(batch, source, tasks)``), so a LEAD checkpoint folder works wherever a run does: ``lead-s2r predict``,
fine-tuning with ``fit``, the CARLA closed-loop agent, and back out with ``lead-s2r export-lead``.

Batches cross into LEAD's input contract and predictions come back into our ISO frame in
:mod:`lead_s2r.models.lead_frame` only; the loader follows :func:`~lead_s2r.models.input_spec.lead_input_spec` (CARLA
labels in LEAD's classes by :mod:`lead_s2r.data.lead_labels`, boxes encoded by :mod:`lead_s2r.data.lead_centernet`).

The package's one TransFuser family: the paper's networks are builders below, each a preset of LEAD's switches.
"""

from collections.abc import Callable, Collection
from typing import Any

import torch
from torch import Tensor, nn

from lead_s2r.errors import UserError
from lead_s2r.models.config import TrajectoryGrid
from lead_s2r.models.input_spec import lead_grids
from lead_s2r.models.inputs import Batch
from lead_s2r.models.lead import LeadEnsemble, load_checkpoint
from lead_s2r.models.lead_config import TARGET_SPEED_CLASSES, LeadConfig
from lead_s2r.models.lead_frame import bev_map_from_lead, from_lead_outputs, to_lead_inputs
from lead_s2r.models.lead_loss import SourceDataset, loss_weights, prefix, radar_feature_scale, visible_bev_pixels
from lead_s2r.models.lead_tfv6 import LeadTFv6


class CameraSelect(nn.Module):
    """LEAD's ``used_cameras`` on a horizontally stitched CARLA mosaic: keep the used tiles, left to right. Applies to
    any (..., H, W) image-aligned tensor, so perspective labels are cropped exactly as the image is."""

    def __init__(self, tiles: int, use: tuple[int, ...] | None) -> None:
        super().__init__()
        if use is not None and any(not 0 <= t < tiles for t in use):
            raise ValueError(f"used camera tiles {use} must index the {tiles} camera tiles")
        self.tiles, self.use = tiles, use

    def forward(self, image: Tensor) -> Tensor:
        if self.use is None:
            return image
        width = image.shape[-1] // self.tiles
        return torch.cat([image[..., t * width : (t + 1) * width] for t in self.use], dim=-1)


class LeadDriver(nn.Module):
    """A LEAD TFv6 / LTFv6 / TFv5 network (``self.network``, LEAD's state_dict keys) driven by our batches.

    Args:
        config: the LEAD architecture (LEAD's field names; see docs/models.md); ignored when ``checkpoint`` is given.
        checkpoint: a LEAD checkpoint folder (config.json + model*.pth): its config and weights, loaded strictly;
            several files matching ``pattern`` make an ensemble (prediction only).
        pretrained: start the image encoder of a ``config``-built network from timm's ImageNet weights, as LEAD's
            training does.
    """

    def __init__(
        self,
        config: LeadConfig | None = None,
        checkpoint: str | None = None,
        pattern: str = "model*.pth",
        pretrained: bool = False,
    ) -> None:
        super().__init__()
        if checkpoint is not None:
            self.network: nn.Module = load_checkpoint(checkpoint, pattern).train()
        else:
            config = config if config is not None else LeadConfig(use_planning_decoder=True)
            self.network = LeadTFv6(config, pretrained=pretrained)
        self.config = config = self.network.config
        tiles = config.mosaic_tiles
        self.camera_select = CameraSelect(len(config.used_cameras), tiles)  # also crops perspective labels
        speeds = torch.tensor(TARGET_SPEED_CLASSES)
        self.register_buffer("target_speed_classes", speeds, persistent=False)  # the target-speed loss's bins
        visible = bev_map_from_lead(visible_bev_pixels(config)[None, None])[0, 0]
        self.register_buffer("bev_visible", visible, persistent=False)  # LEAD's camera frustum on our BEV grid

    @property
    def reads_target_points(self) -> bool:
        """Whether route target points reach the planner (LEAD's CARLA mode: previous, current and next)."""
        return bool(self.config.use_planning_decoder and self.config.use_tp)

    @property
    def box_velocity_loss(self) -> bool:
        """Whether the box loss trains the speed channel (with CARLA labels; LEAD never trains NAVSIM's): LEAD zeroes
        it for LTF, which has no LiDAR motion cues."""
        return not self.config.LTF

    @property
    def radar_scale(self) -> tuple[float, float, float]:
        """What the radar detection loss divides (x, y, speed) by: LEAD's BEV extents and its maximum speed."""
        return radar_feature_scale(self.config)

    @property
    def loss_weights(self) -> dict[str, float]:
        """Each task's weight: LEAD's normalised weight of the term it computes (:func:`lead_loss.loss_weights`). A
        perception term weighs the same for every source; the headings share the waypoint term's (LEAD adds them)."""
        weights = loss_weights(self.config)
        terms = {
            "waypoints": "loss_spatio_temporal_waypoints",
            "headings": "loss_spatio_temporal_waypoints",
            "route": "loss_spatial_route",
            "target_speed": "loss_target_speed",
            "bev_semantic": "loss_bev_semantic",
            "lead_boxes": "loss_center_net_heatmap",
            "semantic": "loss_semantic",
            "depth": "loss_depth",
            "radar": "radar_loss",
        }
        return {
            task: max(weights.get(f"{prefix(s)}{term}", 0.0) for s in SourceDataset) for task, term in terms.items()
        }

    def grid(self, source: str) -> TrajectoryGrid:
        return lead_grids(self.config)[source]

    def tasks(self, source: str) -> frozenset[str]:
        """What the network predicts for ``source``; an ensemble only what :class:`LeadEnsemble` merges."""
        c = self.config
        tasks = c.perception_tasks(source)
        if isinstance(self.network, LeadEnsemble):
            tasks -= {"radar"} if c.carla_leaderboard_mode else c.perception_tasks(source)
        if source in c.sources and c.use_planning_decoder:  # a pretraining network (no planner) plans nothing
            tasks.add("waypoints")
            if c.use_navsim_data and not c.use_tfv5_planning_decoder:
                tasks.add("headings")
            if c.predict_spatial_path or c.use_tfv5_planning_decoder:
                tasks.add("route")
            if c.predict_target_speed:
                tasks.add("target_speed")
        return frozenset(tasks)

    def forward(self, batch: Batch, source: str, tasks: Collection[str] | None = None) -> dict[str, Tensor]:
        """Our outputs for ``source``; ``tasks`` is part of the interface only: LEAD's network runs all its heads."""
        if source not in self.config.sources:
            raise ValueError(f"this LEAD network reads {list(self.config.sources)} batches, not {source!r}")
        if isinstance(self.network, LeadEnsemble) and self.training:
            raise UserError(
                "model.checkpoint holds several model*.pth files (an ensemble, prediction only); to fine-tune, pick "
                "one with model.pattern, e.g. model_0030_0.pth"
            )
        batch = {**batch, "rgb": self.camera_select(batch["rgb"])}
        return from_lead_outputs(self.network(to_lead_inputs(batch, self.config)), source)


def tfv6(**overrides: Any) -> LeadDriver:
    """TFv6, LEAD's CARLA leaderboard network: 3-camera mosaic + LiDAR raster + radar, target points (previous,
    current, next) as planner tokens, route, waypoints (8 @ 4 Hz) and target speed, every CARLA perception head."""
    return _build({"use_planning_decoder": True}, overrides)


def ltfv6_navsim(**overrides: Any) -> LeadDriver:
    """LTFv6 for NAVSIM: TFv6 without LiDAR (``LTF``: a fixed coordinate grid feeds the BEV branch) and without radar
    or target points; 4 cameras at NAVSIM's vertical field of view, speed, acceleration and command tokens, waypoints
    and headings (8 @ 2 Hz), NAVSIM's BEV semantics and vehicle boxes. ``use_carla_data=True`` adds LEAD's CARLA
    heads (the sim-to-real network of LTFv6 + LEAD)."""
    return _build(
        {"use_navsim_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True}, overrides
    )


def ltfv6_wod(**overrides: Any) -> LeadDriver:
    """LTFv6 for WOD-E2E (our extension of LEAD's rules): 3 front cameras, BEV x 0..64 m, no command token, 10
    waypoints @ 2 Hz, no perception head of its own (``use_carla_data=True``: CARLA heads, for a CARLA pre-training)."""
    switches = {"use_waymo_e2e_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True}
    return _build(switches, overrides)


def tfv5(**overrides: Any) -> LeadDriver:
    """TFv5, the ablation: TFv6's backbone with LEAD's GRU planner (``use_tfv5_planning_decoder``), the current
    target point initialising the GRUs instead of being a token; route and waypoints, no target speed."""
    return _build({"use_planning_decoder": True, "use_tfv5_planning_decoder": True}, overrides)


#: The variants by name, as timm registers its models.
VARIANTS: dict[str, Callable[..., LeadDriver]] = {
    "tfv6": tfv6,
    "ltfv6_navsim": ltfv6_navsim,
    "ltfv6_wod": ltfv6_wod,
    "tfv5": tfv5,
}


def _build(switches: dict[str, Any], overrides: dict[str, Any]) -> LeadDriver:
    """A randomly initialised driver of ``switches`` with ``overrides`` (LEAD's field names, and ``pretrained``)."""
    pretrained = bool(overrides.pop("pretrained", False))
    return LeadDriver(LeadConfig.from_json({**switches, **overrides}), pretrained=pretrained)
