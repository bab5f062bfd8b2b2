"""Model configurations: plain dataclasses, so LightningCLI reads them from YAML and checkpoints store them.

Presets follow the LEAD repo (``lead/tfv6``, ``TrainingConfig``): :func:`tfv6_config` (ResNet34 TFv6, ~60M parameters
with token dim 256), :func:`ltfv6_config` (no LiDAR: a fixed coordinate grid feeds the BEV branch) and
:func:`tfv5_config` (GRU refinement initialised with the current target point, which is no decoder token).
"""

import math
from dataclasses import dataclass, field, fields, replace
from numbers import Integral, Real
from typing import Literal, NamedTuple, get_type_hints

#: LEAD's target-speed bins, m/s (``target_speed_classes``); a label is two-hot encoded between neighbours.
TARGET_SPEED_CLASSES = (0.0, 4.0, 8.0, 10.0, 13.89, 16.0, 17.78, 20.0)

#: Vertical field of view of LEAD's NAVSIM camera rig (nuPlan's 63.71 deg across 480 px, 270 of 280 rows kept), deg.
NAVSIM_VERTICAL_FOV_DEG = 2 * math.degrees(math.atan(math.tan(math.radians(63.71 / 2)) * 270 / 480))

#: Where each target-point slot sits in ``target_points`` (B, 3, 2).
TARGET_POINT_SLOTS = ("previous", "current", "next")


class TrajectoryGrid(NamedTuple):
    """A dataset's output grid: ``num_points`` poses at ``t = dt, 2 dt, ...`` seconds.

    A NamedTuple rather than a dataclass so LightningCLI can write it back into saved configs inside a dict.
    """

    num_points: int
    dt: float

    @property
    def times(self) -> tuple[float, ...]:
        return tuple(self.dt * (i + 1) for i in range(self.num_points))


@dataclass(frozen=True)
class BEVGrid:
    """Bird's-eye-view raster in the ISO ego frame.

    Array axis H runs along +x (row ``i`` covers ``x_min + i / ppm``), axis W along +y (column ``j`` covers
    ``y_min + j / ppm``): index order follows coordinate order, so no flip hides in the layout.
    """

    x_min: float = -32.0
    x_max: float = 64.0
    y_min: float = -40.0
    y_max: float = 40.0
    pixels_per_meter: float = 4.0

    @property
    def shape(self) -> tuple[int, int]:
        return (
            round((self.x_max - self.x_min) * self.pixels_per_meter),
            round((self.y_max - self.y_min) * self.pixels_per_meter),
        )


#: LEAD's CARLA leaderboard BEV box (x in [-32, 64], y in [-40, 40], 4 px/m -> 384 x 320).
CARLA_BEV = BEVGrid()
#: NAVSIM's +-32 m square (256 x 256).
NAVSIM_BEV = BEVGrid(-32.0, 32.0, -32.0, 32.0)


def default_grids() -> dict[str, TrajectoryGrid]:
    """LEAD's output grids: CARLA 8 @ 4 Hz, NAVSIM 8 @ 2 Hz, WOD-E2E 10 @ 2 Hz."""
    return {"carla": TrajectoryGrid(8, 0.25), "navsim": TrajectoryGrid(8, 0.5), "wod": TrajectoryGrid(10, 0.5)}


#: The scalar field types :class:`TFv6Config` checks, and what passes for each (numpy's numbers too).
SCALARS: dict[type, type | tuple[type, ...]] = {int: Integral, float: Real, bool: bool, str: str}


@dataclass
class TFv6Config:
    """Everything that shapes a TFv6 / LTFv6 / TFv5 network.

    Per-source dictionaries are keyed by *label space*: a source uses ``label_space.get(source, source)``, so two
    sources that share CARLA classes can share one head instance while CARLA and NAVSIM classes never do.
    """

    # backbone
    image_architecture: str = "resnet34"
    bev_architecture: str = "resnet34"
    pretrained: bool = False
    image_size: tuple[int, int] = (384, 1152)
    #: Vertical field of view of the input rows, degrees: every camera tile is cropped (or padded) by its
    #: calibration to this band around its principal point, so every source shows the world at the same angular
    #: scale. None keeps each tile's full height. Tiles are never squashed: a strip whose aspect differs from
    #: ``image_size`` is letterboxed (see :mod:`lead_s2r.data.transforms`).
    vertical_fov_deg: float | None = None
    bev: BEVGrid = CARLA_BEV
    #: "raster": LiDAR BEV histogram input (TFv6); "coordinates": fixed 2-channel grid (LTFv6);
    #: "latent": learned (C, H, W) tensor as in NAVSIM's LTF.
    bev_input: Literal["raster", "coordinates", "latent"] = "raster"
    lidar_channels: int = 1
    #: Camera ablations: the mosaic is cut into ``camera_tiles`` equal tiles, ``use_tiles`` pick and order them
    #: (None: all), and ``fov_fraction`` keeps that central share of each tile's width.
    camera_tiles: int = 1
    use_tiles: tuple[int, ...] | None = None
    fov_fraction: float = 1.0
    fusion_layers: int = 2
    fusion_heads: int = 4
    fusion_dropout: float = 0.1
    bev_feature_channels: int = 64
    # planning decoder
    decoder: Literal["v6", "v5"] = "v6"
    token_dim: int = 256
    decoder_layers: int = 6
    decoder_heads: int = 8
    decoder_ffn: int = 2048
    decoder_dropout: float = 0.1
    gru_hidden: int = 64
    use_speed: bool = True
    use_acceleration: bool = True
    use_command: bool = True
    num_commands: int = 4
    target_points: tuple[str, ...] = TARGET_POINT_SLOTS
    #: Target points are mapped from [low, high] to [-1, 1] per axis and clamped. "data": when a fit starts, the
    #: range becomes the training sources' statistics (``info.json`` ``statistics.target_points``, see
    #: :func:`lead_s2r.models.inputs.target_point_range`) and is saved with the weights, so validation and
    #: prediction use the range the model was trained with; "fixed": ``target_point_low/high`` as given (LEAD's
    #: x/200, y/50 by default, also the fallback when no training source has target-point statistics).
    target_point_normalisation: Literal["data", "fixed"] = "data"
    target_point_low: tuple[float, float] = (-200.0, -50.0)
    target_point_high: tuple[float, float] = (200.0, 50.0)
    max_speed: float = 20.0
    max_acceleration: float = 4.0
    #: Metres per unit of the route and waypoint heads' per-step outputs (1: LEAD's, the heads output metres). The
    #: output-side twin of ``max_speed``: a small model trained for a few hundred steps cannot grow its last layer to
    #: steps of several metres (AdamW moves a weight by about the learning rate per step), so its trajectories
    #: shrink towards the mean; the smoke twins set it near a typical step (docs/training.md).
    trajectory_scale: float = 1.0
    #: Radians per unit of the heading head's per-step outputs (1: LEAD's). Its targets are hundredths of a radian on
    #: a straight road, so a short run's AdamW steps of about the learning rate make them noise; below 1 the head
    #: moves in smaller steps.
    heading_scale: float = 1.0
    trajectory_grids: dict[str, TrajectoryGrid] = field(default_factory=default_grids)
    predict_headings: bool = True
    num_route_points: int = 10
    target_speed_classes: tuple[float, ...] = TARGET_SPEED_CLASSES
    # radar
    use_radar: bool = True
    radar_sensors: int = 4
    radar_queries: int = 20
    radar_layers: int = 4
    radar_ffn: int = 1024
    radar_sources: tuple[str, ...] = ("carla",)
    # auxiliary heads, per label space
    label_space: dict[str, str] = field(default_factory=dict)
    bev_semantic_classes: dict[str, int] = field(default_factory=lambda: {"carla": 9, "navsim": 7})
    box_classes: dict[str, int] = field(default_factory=lambda: {"carla": 10, "navsim": 1})
    box_yaw_bins: int = 12
    semantic_classes: dict[str, int] = field(default_factory=lambda: {"carla": 10})
    depth_sources: tuple[str, ...] = ("carla",)
    max_depth: float = 50.0

    def __post_init__(self) -> None:
        """A scalar of another type than its field's (a YAML null or string where a size goes) is named here, not
        met as a TypeError deep in a torch constructor."""
        hints = get_type_hints(type(self))
        for name in (f.name for f in fields(self) if hints[f.name] in SCALARS):
            value, kind = getattr(self, name), hints[name]
            if not isinstance(value, SCALARS[kind]) or (kind is not bool and isinstance(value, bool)):
                raise ValueError(f"TFv6Config.{name} is {value!r}, not {kind.__name__}")

    def space(self, source: str) -> str:
        """The label space a source's perception targets live in."""
        return self.label_space.get(source, source)


def tfv6_config(**overrides: object) -> TFv6Config:
    """TFv6 as in LEAD's CARLA model: camera + LiDAR + radar, ResNet34 encoders, token dim 256."""
    return replace(TFv6Config(), **overrides)


def ltfv6_config(**overrides: object) -> TFv6Config:
    """LTFv6 for NAVSIM: 4-camera 1920x270 mosaic at NAVSIM's vertical field of view, no LiDAR and no radar;
    acceleration and command tokens."""
    base = TFv6Config(
        image_size=(270, 1920),
        vertical_fov_deg=NAVSIM_VERTICAL_FOV_DEG,
        bev=NAVSIM_BEV,
        bev_input="coordinates",
        lidar_channels=2,
        use_radar=False,
        target_points=(),
    )
    return replace(base, **overrides)


def tfv5_config(**overrides: object) -> TFv6Config:
    """TFv5 ablation as LEAD's ``tfv5_planning_decoder``: the decoder context holds the speed and command tokens
    only; the current target point never becomes a token, it initialises the GRUs' hidden state."""
    base = TFv6Config(decoder="v5", target_points=(), use_acceleration=False, use_radar=False, predict_headings=False)
    return replace(base, **overrides)


@dataclass
class EgoMLPConfig:
    """The ego-status MLP baseline (NAVSIM's EgoStatusMLP): speed, acceleration, command -> trajectory."""

    hidden: int = 512
    layers: int = 3
    num_commands: int = 4
    max_speed: float = 20.0
    max_acceleration: float = 4.0
    trajectory_grids: dict[str, TrajectoryGrid] = field(default_factory=default_grids)
