"""LEAD's network with the interface our LightningModule trains and predicts with (``tasks``, ``grid``,
``forward(batch, source, tasks)``), so a LEAD checkpoint folder works wherever a run does: ``lead-s2r predict``,
fine-tuning with ``fit``, and back out with ``lead-s2r export-lead``.

Batches cross into LEAD's input contract and predictions come back into our ISO frame in
:mod:`lead_s2r.models.lead_frame` only. The loader follows :func:`transform_config`: LEAD's image size and camera
band, its BEV extent for the LiDAR raster, radar and target points when the network reads them, and no perception
labels (this wrapper trains the planner's outputs: waypoints, NAVSIM headings, CARLA route).
"""

from collections.abc import Collection
from pathlib import Path

from torch import Tensor, nn

from lead_s2r.models.config import (
    NAVSIM_VERTICAL_FOV_DEG,
    TARGET_POINT_SLOTS,
    BEVGrid,
    TFv6Config,
    TrajectoryGrid,
    default_grids,
)
from lead_s2r.models.inputs import Batch
from lead_s2r.models.lead import LeadEnsemble, load_checkpoint, read_config
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_frame import from_lead_outputs, to_lead_inputs
from lead_s2r.models.lead_tfv6 import LeadTFv6


def lead_source(config: LeadConfig) -> str:
    """The one source a LEAD network plans for: its target dataset's grid (8 poses at 2 Hz NAVSIM, 4 Hz CARLA)."""
    return "carla" if config.carla_leaderboard_mode else "navsim"


def transform_config(config: LeadConfig) -> TFv6Config:
    """What our loader must produce for this LEAD network (see the module docstring)."""
    source = lead_source(config)
    return TFv6Config(
        image_size=(config.final_image_height, config.final_image_width),
        vertical_fov_deg=NAVSIM_VERTICAL_FOV_DEG if config.use_navsim_data else None,
        bev=BEVGrid(
            float(config.min_x_meter),
            float(config.max_x_meter),
            float(config.min_y_meter),
            float(config.max_y_meter),
            float(config.pixels_per_meter),
        ),
        bev_input="coordinates" if config.LTF else "raster",
        lidar_channels=2 if config.LTF else 1,
        target_points=TARGET_POINT_SLOTS if config.use_tp or config.use_tfv5_planning_decoder else (),
        trajectory_grids={source: default_grids()[source]},
        use_radar=config.has_radar_detector,
        radar_sources=("carla",),
        bev_semantic_classes={},
        box_classes={},
        semantic_classes={},
        depth_sources=(),
    )


class LeadDriver(nn.Module):
    """A LEAD TFv6 / LTFv6 / TFv5 network (``self.network``, LEAD's state_dict keys) driven by our batches.

    Args:
        config: the LEAD architecture (LEAD's field names; see docs/models.md); ignored when ``checkpoint`` is given.
        checkpoint: a LEAD checkpoint folder (config.json + model*.pth): its config and weights, loaded strictly;
            several matching files make an ensemble (prediction only).
        pattern: which weight files of ``checkpoint`` to load.
    """

    def __init__(
        self, config: LeadConfig | None = None, checkpoint: str | None = None, pattern: str = "model*.pth"
    ) -> None:
        super().__init__()
        if checkpoint is not None:
            config = read_config(Path(checkpoint))
            self.network: nn.Module = load_checkpoint(checkpoint, pattern).train()
        else:
            config = config if config is not None else LeadConfig(use_planning_decoder=True)
            self.network = LeadTFv6(config)
        if not config.use_planning_decoder:
            raise ValueError("LeadDriver needs use_planning_decoder=true (a pretraining network has no planner)")
        self.config = config
        self.source = lead_source(config)

    @property
    def transform_config(self) -> TFv6Config:
        return transform_config(self.config)

    def grid(self, source: str) -> TrajectoryGrid:
        return default_grids()[self.source]

    def tasks(self, source: str) -> frozenset[str]:
        if source != self.source:
            return frozenset()
        tasks = {"waypoints"}
        if self.config.use_navsim_data and not self.config.use_tfv5_planning_decoder:
            tasks.add("headings")
        if self.config.predict_spatial_path or self.config.use_tfv5_planning_decoder:
            tasks.add("route")
        return frozenset(tasks)

    def forward(self, batch: Batch, source: str, tasks: Collection[str] | None = None) -> dict[str, Tensor]:
        if source != self.source:
            raise ValueError(f"this LEAD network plans for {self.source!r}, not {source!r}")
        if isinstance(self.network, LeadEnsemble) and self.training:
            raise ValueError("a LEAD ensemble predicts only; fine-tune one member (pattern=model_0030_0.pth)")
        return from_lead_outputs(self.network(to_lead_inputs(batch, self.config)))
