"""LEAD's network with the interface our LightningModule trains and predicts with (``tasks``, ``grid``,
``forward(batch, source, tasks)``), so a LEAD checkpoint folder works wherever a run does: ``lead-s2r predict``,
fine-tuning with ``fit``, the CARLA closed-loop agent, and back out with ``lead-s2r export-lead``.

Batches cross into LEAD's input contract and predictions come back into our ISO frame in
:mod:`lead_s2r.models.lead_frame` only. The loader follows
:func:`~lead_s2r.models.input_spec.lead_input_spec`: LEAD's image size and camera band, its BEV extent for the LiDAR
raster, radar and target points when the network reads them, and the labels of its heads: the planner's outputs
(waypoints, NAVSIM headings, CARLA route and target speed) for every source it reads, on its target's grid, BEV
semantics and boxes of each source it has heads for (CARLA labels remapped to LEAD's 13 BEV and 8 box classes by
:mod:`lead_s2r.data.lead_labels`, boxes in LEAD's CenterNet encoding by :mod:`lead_s2r.data.lead_centernet`), and with
CARLA data CARLA perspective semantics, depth and radar detection.
"""

from collections.abc import Collection
from pathlib import Path

import torch
from torch import Tensor, nn

from lead_s2r.errors import UserError
from lead_s2r.models.backbone import CameraSelect
from lead_s2r.models.config import TrajectoryGrid
from lead_s2r.models.input_spec import lead_grids
from lead_s2r.models.inputs import Batch
from lead_s2r.models.lead import LeadEnsemble, load_checkpoint, read_config
from lead_s2r.models.lead_config import TARGET_SPEED_CLASSES, LeadConfig
from lead_s2r.models.lead_frame import bev_map_from_lead, from_lead_outputs, to_lead_inputs
from lead_s2r.models.lead_loss import SourceDataset, loss_weights, prefix, radar_feature_scale, visible_bev_pixels
from lead_s2r.models.lead_tfv6 import LeadTFv6


class LeadDriver(nn.Module):
    """A LEAD TFv6 / LTFv6 / TFv5 network (``self.network``, LEAD's state_dict keys) driven by our batches.

    Args:
        config: the LEAD architecture (LEAD's field names; see docs/models.md); ignored when ``checkpoint`` is given.
        checkpoint: a LEAD checkpoint folder (config.json + model*.pth): its config and weights, loaded strictly;
            several matching files make an ensemble (prediction only).
        pattern: which weight files of ``checkpoint`` to load.
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
            config = read_config(Path(checkpoint))
            self.network: nn.Module = load_checkpoint(checkpoint, pattern).train()
        else:
            config = config if config is not None else LeadConfig(use_planning_decoder=True)
            self.network = LeadTFv6(config, pretrained=pretrained)
        self.config = config
        tiles = config.mosaic_tiles
        self.camera_select = CameraSelect(len(config.used_cameras), tiles, 1.0)  # also crops perspective labels
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
        """Each task's weight: LEAD's normalised weight of the term it computes (:func:`lead_loss.loss_weights`,
        normalised over LEAD's whole table). A perception term weighs the same for every source that has it, and the
        headings share the waypoint term's weight (LEAD adds them into it)."""
        weights = loss_weights(self.config)

        def term(name: str) -> float:
            return max(weights.get(f"{prefix(source)}{name}", 0.0) for source in SourceDataset)

        planning = weights["loss_spatio_temporal_waypoints"]
        return {
            "waypoints": planning,
            "headings": planning,
            "route": weights["loss_spatial_route"],
            "target_speed": weights["loss_target_speed"],
            "bev_semantic": term("loss_bev_semantic"),
            "lead_boxes": term("loss_center_net_heatmap"),
            "semantic": term("loss_semantic"),
            "depth": term("loss_depth"),
            "radar": term("radar_loss"),
        }

    def grid(self, source: str) -> TrajectoryGrid:
        return lead_grids(self.config)[source]

    def tasks(self, source: str) -> frozenset[str]:
        c = self.config
        tasks = c.perception_tasks(source)
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
