"""LEAD's network with the interface our LightningModule trains and predicts with (``tasks``, ``grid``,
``forward(batch, source, tasks)``), so a LEAD checkpoint folder works wherever a run does: ``lead-s2r predict``,
fine-tuning with ``fit``, and back out with ``lead-s2r export-lead``.

Batches cross into LEAD's input contract and predictions come back into our ISO frame in
:mod:`lead_s2r.models.lead_frame` only. The loader follows :func:`transform_config`: LEAD's image size and camera
band, its BEV extent for the LiDAR raster, radar and target points when the network reads them, and the labels of the
heads whose classes are ours too: the planner's outputs (waypoints, NAVSIM headings, CARLA route) for the source the
network plans for, NAVSIM BEV semantics, and with CARLA data (LEAD's mixed training) CARLA perspective semantics and
depth. LEAD's CARLA BEV classes, boxes and radar detections are not trained through this wrapper.
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
from lead_s2r.models.lead_config import NAVSIM_BEV_SEMANTIC_CLASSES, LeadConfig
from lead_s2r.models.lead_frame import from_lead_outputs, to_lead_inputs
from lead_s2r.models.lead_tfv6 import LeadTFv6


def lead_source(config: LeadConfig) -> str:
    """The one source a LEAD network plans for: its target dataset's grid (8 poses at 2 Hz NAVSIM, 4 Hz CARLA)."""
    return "carla" if config.carla_leaderboard_mode else "navsim"


def lead_sources(config: LeadConfig) -> tuple[str, ...]:
    """The sources whose batches the network reads: the one it plans for, and CARLA when it has CARLA heads."""
    source = lead_source(config)
    return (source, "carla") if config.use_carla_data and source != "carla" else (source,)


def perception_tasks(config: LeadConfig, source: str) -> set[str]:
    """Our perception tasks a LEAD network's heads produce for ``source`` in our label spaces."""
    tasks = set()
    if source == "navsim" and config.use_navsim_data and config.use_bev_semantic:
        tasks.add("bev_semantic")
    if source == "carla" and config.use_carla_data and config.use_semantic:
        tasks.add("semantic")
    if source == "carla" and config.use_carla_data and config.use_depth:
        tasks.add("depth")
    return tasks


def transform_config(config: LeadConfig) -> TFv6Config:
    """What our loader must produce for this LEAD network (see the module docstring)."""
    grids, carla = default_grids(), perception_tasks(config, "carla")
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
        trajectory_grids={source: grids[source] for source in lead_sources(config)},
        use_radar=config.has_radar_detector,
        radar_sources=("carla",),
        bev_semantic_classes={"navsim": NAVSIM_BEV_SEMANTIC_CLASSES} if perception_tasks(config, "navsim") else {},
        box_classes={},
        semantic_classes={"carla": config.num_semantic_classes} if "semantic" in carla else {},
        depth_sources=("carla",) if "depth" in carla else (),
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
        return default_grids()[source]

    def tasks(self, source: str) -> frozenset[str]:
        tasks = perception_tasks(self.config, source)
        if source == self.source:
            tasks.add("waypoints")
            if self.config.use_navsim_data and not self.config.use_tfv5_planning_decoder:
                tasks.add("headings")
            if self.config.predict_spatial_path or self.config.use_tfv5_planning_decoder:
                tasks.add("route")
        return frozenset(tasks)

    def forward(self, batch: Batch, source: str, tasks: Collection[str] | None = None) -> dict[str, Tensor]:
        if source not in lead_sources(self.config):
            raise ValueError(f"this LEAD network reads {list(lead_sources(self.config))} batches, not {source!r}")
        if isinstance(self.network, LeadEnsemble) and self.training:
            raise ValueError("a LEAD ensemble predicts only; fine-tune one member (pattern=model_0030_0.pth)")
        return from_lead_outputs(self.network(to_lead_inputs(batch, self.config)))
