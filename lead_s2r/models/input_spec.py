"""What a model asks of its data: the inputs and labels the data transforms build, per source, on which grids.

The data side (``lead_s2r.data``) is configured by an :class:`InputSpec`, never by a model's own configuration: a
model config produces one (:func:`input_spec`), so a model with other inputs (the ego-status MLP: no sensor, no
label) says so plainly instead of posing as a TransFuser configuration.
"""

from dataclasses import dataclass, field

from lead_s2r.models.config import CARLA_BEV, NAVSIM_VERTICAL_FOV_DEG, BEVGrid, EgoMLPConfig, TrajectoryGrid
from lead_s2r.models.lead_config import NAVSIM_BEV_SEMANTIC_CLASSES, NAVSIM_BOX_CLASSES, LeadConfig


@dataclass(frozen=True)
class InputSpec:
    """The inputs and labels a model reads, and their grids.

    Attributes:
        trajectory_grids: per source, the output grid its future is resampled to (the sources the model knows).
        image_size: (H, W) of the camera input.
        vertical_fov_deg: rows kept around each camera tile's principal point (None: all rows).
        equal_tiles: the model cuts equal tiles from a mosaic that fills ``image_size`` (the camera ablations).
        bev: the BEV grid of the LiDAR raster and the BEV labels.
        radar: the model reads radar points; ``radar_sources`` also get radar detection targets.
        label_space: source -> label space of its perception labels (default: the source's own name).
        bev_semantic_classes, semantic_classes: per label space, the classes of each perception head.
        depth_sources: label spaces with a depth head; ``max_depth`` decodes stored depth PNGs without a scale.
        lead_box_classes: per label space, the classes of a box head trained with LEAD's CenterNet encoding
            (``lead_s2r.data.lead_centernet``): 1 (NAVSIM's vehicles) or LEAD's 8 CARLA classes; ``lead_yaw_bins``
            yaw bins (LEAD's ``num_dir_bins``).
        lead_carla_labels: CARLA labels in LEAD's class tables (``lead_s2r.data.lead_labels``): None (ours),
            "leaderboard" or "sim2real" (LEAD's two modes).
    """

    trajectory_grids: dict[str, TrajectoryGrid]
    image_size: tuple[int, int] = (384, 1152)
    vertical_fov_deg: float | None = None
    equal_tiles: bool = False
    bev: BEVGrid = CARLA_BEV
    lidar_raster: bool = False
    radar: bool = False
    radar_sources: tuple[str, ...] = ()
    label_space: dict[str, str] = field(default_factory=dict)
    bev_semantic_classes: dict[str, int] = field(default_factory=dict)
    semantic_classes: dict[str, int] = field(default_factory=dict)
    depth_sources: tuple[str, ...] = ()
    max_depth: float = 50.0
    num_route_points: int = 10
    lead_box_classes: dict[str, int] = field(default_factory=dict)
    lead_yaw_bins: int = 12
    lead_carla_labels: str | None = None

    def __post_init__(self) -> None:
        if self.lead_carla_labels not in (None, "leaderboard", "sim2real"):
            raise ValueError(f"lead_carla_labels: {self.lead_carla_labels!r}; use None, 'leaderboard' or 'sim2real'")

    def space(self, source: str) -> str:
        """The label space a source's perception labels live in."""
        return self.label_space.get(source, source)


def input_spec(config: EgoMLPConfig | LeadConfig) -> InputSpec:
    """The inputs a model built from ``config`` reads (the ego-status MLP: its output grids only)."""
    if isinstance(config, EgoMLPConfig):
        return InputSpec(trajectory_grids=dict(config.trajectory_grids))
    return lead_input_spec(config)


def lead_grids(config: LeadConfig) -> dict[str, TrajectoryGrid]:
    """The planner's one output grid for every source the network reads: LEAD trains a mixed source's waypoints on its
    target's grid (CARLA 8 @ 4 Hz, NAVSIM 8 @ 2 Hz, WOD-E2E 10 @ 2 Hz, or the config's override)."""
    grid = TrajectoryGrid(config.num_way_points_prediction, config.waypoint_interval_s)
    return {source: grid for source in config.sources}


def lead_input_spec(config: LeadConfig) -> InputSpec:
    """What LEAD's network (``lead_s2r.models.lead_driver.LeadDriver``) reads: LEAD's image size, BEV extent, sensors
    and the labels of its heads (:meth:`LeadConfig.perception_tasks`), CARLA's in LEAD's class tables."""
    tasks = {source: config.perception_tasks(source) for source in ("navsim", "carla")}
    carla = tasks["carla"]
    cameras = len(config.used_cameras) if config.mosaic_tiles else config.num_used_cameras  # LeadDriver crops
    (x0, x1), (y0, y1) = config.bev_extent
    return InputSpec(
        trajectory_grids=lead_grids(config),
        image_size=(config.final_image_height, config.final_image_width // config.num_used_cameras * cameras),
        vertical_fov_deg=NAVSIM_VERTICAL_FOV_DEG if config.use_navsim_data else None,
        equal_tiles=config.mosaic_tiles is not None,
        bev=BEVGrid(float(x0), float(x1), float(y0), float(y1), float(config.pixels_per_meter)),
        lidar_raster=not config.LTF,
        radar=config.has_radar_detector,
        radar_sources=("carla",) if "radar" in carla else (),
        bev_semantic_classes=_classes(
            {"navsim": NAVSIM_BEV_SEMANTIC_CLASSES, "carla": config.num_bev_semantic_classes}, "bev_semantic", tasks
        ),
        semantic_classes={"carla": config.num_semantic_classes} if "semantic" in carla else {},
        depth_sources=("carla",) if "depth" in carla else (),
        num_route_points=config.num_route_points_prediction,
        lead_box_classes=_classes({"navsim": NAVSIM_BOX_CLASSES, "carla": config.num_bb_classes}, "lead_boxes", tasks),
        lead_yaw_bins=config.num_dir_bins,
        lead_carla_labels="leaderboard" if config.carla_leaderboard_mode else "sim2real",
    )


def _classes(counts: dict[str, int], task: str, tasks: dict[str, set[str]]) -> dict[str, int]:
    """``counts`` of the sources whose tasks include ``task``."""
    return {source: n for source, n in counts.items() if task in tasks[source]}
