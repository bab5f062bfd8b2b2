"""What a model asks of its data: the inputs and labels the data transforms build, per source, on which grids.

The data side (``lead_s2r.data``) is configured by an :class:`InputSpec`, never by a model's own configuration: a
model config produces one (:func:`input_spec`), so a model with other inputs (the ego-status MLP: no sensor, no
label) says so plainly instead of posing as a TFv6 configuration.
"""

from dataclasses import dataclass, field

from lead_s2r.models.config import CARLA_BEV, BEVGrid, EgoMLPConfig, TFv6Config, TrajectoryGrid


@dataclass(frozen=True)
class InputSpec:
    """The inputs and labels a model reads, and their grids.

    Attributes:
        trajectory_grids: per source, the output grid its future is resampled to (the sources the model knows).
        image_size: (H, W) of the camera input.
        vertical_fov_deg: rows kept around each camera tile's principal point (None: all rows).
        equal_tiles: the model cuts equal tiles from a mosaic that fills ``image_size`` (the camera ablations).
        bev: the BEV grid of the LiDAR raster and the BEV labels.
        lidar_raster: the model reads the LiDAR BEV raster.
        radar: the model reads radar points; ``radar_sources`` also get radar detection targets.
        label_space: source -> label space of its perception labels (default: the source's own name).
        bev_semantic_classes, box_classes, semantic_classes: per label space, the classes of each perception head.
        depth_sources: label spaces with a depth head; ``max_depth`` decodes stored depth PNGs without a scale.
        num_route_points: route checkpoints per sample.
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
    box_classes: dict[str, int] = field(default_factory=dict)
    semantic_classes: dict[str, int] = field(default_factory=dict)
    depth_sources: tuple[str, ...] = ()
    max_depth: float = 50.0
    num_route_points: int = 10

    def space(self, source: str) -> str:
        """The label space a source's perception labels live in."""
        return self.label_space.get(source, source)


def input_spec(config: TFv6Config | EgoMLPConfig) -> InputSpec:
    """The inputs a model built from ``config`` reads: every sensor and label of a TFv6-family config; the ego state
    and its output grids only for the ego-status MLP."""
    if isinstance(config, EgoMLPConfig):
        return InputSpec(trajectory_grids=dict(config.trajectory_grids))
    return InputSpec(
        trajectory_grids=dict(config.trajectory_grids),
        image_size=tuple(config.image_size),
        vertical_fov_deg=config.vertical_fov_deg,
        equal_tiles=config.use_tiles is not None or config.fov_fraction < 1.0,
        bev=config.bev,
        lidar_raster=config.bev_input == "raster",
        radar=config.use_radar,
        radar_sources=tuple(config.radar_sources),
        label_space=dict(config.label_space),
        bev_semantic_classes=dict(config.bev_semantic_classes),
        box_classes=dict(config.box_classes),
        semantic_classes=dict(config.semantic_classes),
        depth_sources=tuple(config.depth_sources),
        max_depth=config.max_depth,
        num_route_points=config.num_route_points,
    )
