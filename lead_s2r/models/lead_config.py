"""LEAD's ``TrainingConfig`` as a typed dataclass: the fields that shape a TFv6 / LTFv6 / TFv5 network, under LEAD's own
names, and the rules LEAD uses to derive everything else from them.

LEAD writes ``config.json`` next to every checkpoint (``TrainingConfig.training_dict()``, about 196 keys). Reading it
back, LEAD takes class attributes from the file, casts "overridable" properties to their default's type, and silently
recomputes plain properties (BEV extent, image size, anchors, status-token switches ...) from the target dataset, so the
derived numbers in a file are informational. :meth:`LeadConfig.from_json` does the same, which is why a config.json
edited by hand must change the *switch* (``use_navsim_data``, ``used_cameras``, ``pixels_per_meter``), not the derived
value. Keys this class does not model are ignored, as LEAD ignores keys it does not know. A value of another JSON type
than its field's (``"n_layer": "x"``, ``"use_depth": 7``) is an error naming the field: LEAD's cast would turn 7 into
True and a string into a traceback deep in the network's constructor.

Our extensions, where LEAD's code has no switch (docs/models.md, "LEAD's own architecture"): the WOD-E2E target builds
(LEAD's own cannot: its camera calibration imports a function missing from its public code, see :data:`CAMERA_TILE`),
its past-state token slots stay off, and ``use_previous_tp`` / ``use_next_tp``, ``num_way_points_prediction`` and
``waypoint_interval_s`` may be set in a file. LEAD's loader recomputes these from its rules, so a network that overrides
them loads in LEAD only where the rules give the same values. ``camera_tile_size`` and the toy scales
(:data:`TOY_SCALES`), set by the smoke twins (``recipes/smoke/twin_lead.yaml``), are not LEAD's: it cannot load them.
"""

from dataclasses import asdict, dataclass, fields
from typing import Any, get_args, get_type_hints

import timm

from lead_s2r.errors import UserError
from lead_s2r.fields import describe, fits
from lead_s2r.schema import TargetDataset

#: Camera tile of each target: (width, cropped height) in pixels (``BaseConfig.camera_calibration``). WOD-E2E's is
#: ours: LEAD's constants give each front camera 972 x 1080 (cropped) and a down-sample factor of 3, but the function
#: that would turn them into its calibration is missing from LEAD's code; 324 x 360 is those numbers divided by 3
#: (WOD-E2E's 972 x 1079 front images, three side by side, fill the 972 x 360 input).
CAMERA_TILE = {
    TargetDataset.CARLA_LEADERBOARD2_3CAMERAS: (384, 384),
    TargetDataset.CARLA_LEADERBOARD2_6CAMERAS: (384, 384),
    TargetDataset.NAVSIM_4CAMERAS: (480, 270),
    TargetDataset.WAYMO_E2E_2025_3CAMERAS: (324, 360),
}
NUM_CAMERAS = {
    TargetDataset.CARLA_LEADERBOARD2_3CAMERAS: 3,
    TargetDataset.CARLA_LEADERBOARD2_6CAMERAS: 6,
    TargetDataset.NAVSIM_4CAMERAS: 4,
    TargetDataset.WAYMO_E2E_2025_3CAMERAS: 3,
}
#: CARLA target-speed bins, m/s, exactly as LEAD writes them.
TARGET_SPEED_CLASSES = (0.0, 4.0, 8.0, 10.0, 13.88888888, 16.0, 17.77777777, 20.0)
#: ``len(NavSimBEVSemanticClass)`` and ``len(NavSimBBClass)``.
NAVSIM_BEV_SEMANTIC_CLASSES = 7
NAVSIM_BOX_CLASSES = 1
#: ``training_used_lidar_steps`` is a fixed property (> 1 adds the CenterNet velocity head).
TRAINING_USED_LIDAR_STEPS = 10
#: Our toy-scale fields (1.0: LEAD's network), which LEAD's loader cannot read.
TOY_SCALES = ("status_scale", "trajectory_scale", "heading_scale")
#: WOD-E2E's maximum speed for the speed token, m/s (LEAD's ``max_speed``).
WOD_MAX_SPEED = 33.33


@dataclass
class LeadConfig:
    """The architecture-relevant part of LEAD's ``TrainingConfig`` and its optimizer (defaults: LEAD main, 4489176)."""

    image_architecture: str = "resnet34"
    lidar_architecture: str = "resnet34"
    LTF: bool = False  # LEAD's field name, kept so config.json round-trips
    n_layer: int = 2
    n_head: int = 4
    block_exp: int = 4
    embd_pdrop: float = 0.1
    attn_pdrop: float = 0.1
    resid_pdrop: float = 0.1
    gpt_linear_layer_init_mean: float = 0.0
    gpt_linear_layer_init_std: float = 0.02
    gpt_layer_norm_init_weight: float = 1.0
    pixels_per_meter: float = 4.0
    perspective_downsample_factor: int = 1
    bev_upsample_factor: int = 2
    bev_down_sample_factor: int = 4
    bev_features_chanels: int = 64
    bb_input_channel: int = 64
    use_semantic: bool = True
    num_semantic_classes: int = 10
    deconv_channel_num_0: int = 128
    deconv_channel_num_1: int = 64
    deconv_channel_num_2: int = 32
    deconv_scale_factor_0: int = 4
    deconv_scale_factor_1: int = 8
    use_bev_semantic: bool = True
    num_bev_semantic_classes: int = 13
    detect_boxes: bool = True
    num_bb_classes: int = 8
    num_dir_bins: int = 12
    use_carla_data: bool = True
    use_navsim_data: bool = False
    use_waymo_e2e_data: bool = False
    carla_root: str = "data/carla_leaderboard2"
    use_radars: bool = True
    num_radar_sensors: int = 4
    num_radar_queries: int = 20
    radar_token_dim: int = 256
    radar_hidden_dim_tokenizer: int = 1024
    radar_tf_dim_ff: int = 1024
    radar_dropout: float = 0.1
    radar_num_heads: int = 8
    radar_num_layers: int = 4
    radar_hidden_dim_decoder: int = 1024
    use_velocity: bool = True
    use_planning_decoder: bool = False
    use_tfv5_planning_decoder: bool = False
    gru_hidden_size: int = 64
    transfuser_token_dim: int = 64
    transfuser_num_bev_cross_attention_heads: int = 8
    transfuser_num_bev_cross_attention_layers: int = 6
    predict_temporal_spatial_waypoints: bool = True
    num_route_points_prediction: int = 10
    use_mixed_precision_training: bool = True
    lr: float = 3e-4  # LEAD's optimizer settings (models/lead_loss.py)
    weight_decay: float = 0.01
    # overridable properties (None: derived by LEAD's rule)
    used_cameras: list[bool] | None = None
    use_depth: bool | None = None
    radar_detection: bool | None = None
    use_radar_detection: bool | None = None
    use_discrete_command: bool | None = None
    use_past_positions: bool | None = None
    use_past_speeds: bool | None = None
    num_past_samples_used: int | None = None
    use_previous_tp: bool | None = None
    use_next_tp: bool | None = None
    num_way_points_prediction: int | None = None
    waypoint_interval_s: float | None = None  # ours: seconds between waypoints (LEAD: waypoints_spacing, in frames)
    camera_tile_size: list[int] | None = None  # ours: (width, height) of a camera tile; None: the target's CAMERA_TILE
    use_cosine_annealing_with_restarts: bool | None = None  # LEAD's schedule: restarts except for WOD-E2E
    epochs: int | None = None  # LEAD's run length: CARLA 31, NAVSIM 61, WOD-E2E 20
    # ours, toy scales for runs of a few hundred steps (the smoke twins); 1.0 is LEAD's network, export-lead refuses
    # any other value. AdamW moves a weight by about the learning rate per step: too few steps to grow the planner's
    # input and output layers to the world's scales (docs/training.md, "The output scale").
    status_scale: float = 1.0  # multiplies the planner's speed and acceleration inputs after LEAD's normalisation
    trajectory_scale: float = 1.0  # metres per unit of the route and waypoint heads' per-step outputs
    heading_scale: float = 1.0  # radians per unit of the heading head's per-step outputs

    def __post_init__(self) -> None:
        """Every field has its JSON type (a YAML recipe's null or string where a size goes is named here, not met as a
        TypeError deep in a torch constructor), then LEAD's rules fill the derived ones."""
        hints = get_type_hints(type(self))
        for f in fields(self):
            setattr(self, f.name, _typed(f.name, getattr(self, f.name), hints[f.name]))
        for name in ("image_architecture", "lidar_architecture"):
            if not timm.is_model(architecture := getattr(self, name)):
                raise UserError(f"config.json: {name} {architecture!r} is no timm architecture (timm.list_models())")
        target = self.target_dataset
        wod = self.is_wod
        defaults = {
            "used_cameras": [True] * NUM_CAMERAS[target],
            "use_depth": self.carla_leaderboard_mode,
            "radar_detection": self.carla_leaderboard_mode,
            "use_radar_detection": self.carla_leaderboard_mode,
            "use_discrete_command": not wod,
            "use_past_positions": False,  # LEAD: on for WOD-E2E, slots its forward never fills; ours: off
            "use_past_speeds": False,
            "num_past_samples_used": 0,  # LEAD: 6 with past positions or speeds, which are refused below
            "use_previous_tp": self.use_tp,
            "use_next_tp": self.use_tp,
            "num_way_points_prediction": 10 if wod else 8,  # CARLA 8 @ 4 Hz, NAVSIM 8 @ 2 Hz, WOD-E2E 10 @ 2 Hz
            "waypoint_interval_s": 0.25 if self.carla_leaderboard_mode else 0.5,
            "use_cosine_annealing_with_restarts": not wod,
            "epochs": 31 if self.carla_leaderboard_mode else 20 if wod else 61,
        }
        for name, default in defaults.items():
            if getattr(self, name) is None:
                setattr(self, name, default)
        if self.use_past_positions or self.use_past_speeds:
            raise UserError(
                "config.json: use_past_positions / use_past_speeds add planner token slots that LEAD's forward never "
                "fills (it fails with a shape error); set both to false"
            )
        if (self.use_previous_tp or self.use_next_tp) and not self.use_tp:
            raise UserError(
                "config.json: use_previous_tp / use_next_tp need the current target point's encoder, which only "
                "CARLA leaderboard mode builds (use_tp); set them to false"
            )
        if self.num_way_points_prediction < 1 or self.waypoint_interval_s <= 0:
            raise UserError(
                f"config.json: num_way_points_prediction={self.num_way_points_prediction} and waypoint_interval_s="
                f"{self.waypoint_interval_s} must be positive"
            )
        for name in TOY_SCALES:
            if getattr(self, name) <= 0:
                raise UserError(f"config.json: {name}={getattr(self, name)} must be positive (1.0: LEAD's network)")
        size = self.camera_tile_size
        if size is not None and (len(size) != 2 or any(int(n) != n or n < 32 or n % 32 for n in size)):
            raise UserError(f"config.json: camera_tile_size={size} must be [width, height], multiples of 32 pixels")
        if len(self.used_cameras) != NUM_CAMERAS[target] or not any(self.used_cameras):
            raise UserError(
                f"config.json: used_cameras={self.used_cameras} must hold {NUM_CAMERAS[target]} flags, one true"
            )

    @classmethod
    def from_json(cls, values: dict[str, Any]) -> "LeadConfig":
        """Read a LEAD config.json dict as LEAD's loader does (unknown and derived keys ignored)."""
        return cls(**{f.name: values[f.name] for f in fields(cls) if f.name in values})

    def to_json(self) -> dict[str, Any]:
        """Every field LEAD's loader reads, plus the derived values (informational, as in LEAD's own files)."""
        out = asdict(self)
        out.update(
            target_dataset=int(self.target_dataset),
            num_available_cameras=NUM_CAMERAS[self.target_dataset],
            num_used_cameras=self.num_used_cameras,
            min_x_meter=self.min_x_meter,
            max_x_meter=self.max_x_meter,
            min_y_meter=self.min_y_meter,
            max_y_meter=self.max_y_meter,
            lidar_width_pixel=self.lidar_width_pixel,
            lidar_height_pixel=self.lidar_height_pixel,
            lidar_vert_anchors=self.lidar_vert_anchors,
            lidar_horz_anchors=self.lidar_horz_anchors,
            final_image_width=self.final_image_width,
            final_image_height=self.final_image_height,
            img_vert_anchors=self.img_vert_anchors,
            img_horz_anchors=self.img_horz_anchors,
            training_used_lidar_steps=TRAINING_USED_LIDAR_STEPS,
            discrete_command_dim=self.discrete_command_dim,
            use_acceleration=self.use_acceleration,
            max_speed=self.max_speed,
            max_acceleration=self.max_acceleration,
            use_tp=self.use_tp,
            target_points_normalization_constants=[list(self.target_points_normalization_constants)],
            predict_target_speed=self.predict_target_speed,
            predict_spatial_path=self.predict_spatial_path,
            target_speed_classes=list(TARGET_SPEED_CLASSES),
            target_speeds=list(TARGET_SPEED_CLASSES),
            navsim_num_bev_semantic_classes=NAVSIM_BEV_SEMANTIC_CLASSES,
            navsim_num_bb_classes=NAVSIM_BOX_CLASSES,
            mixed_data_training=self.mixed_data_training,
            carla_leaderboard_mode=self.carla_leaderboard_mode,
            channel_last=True,
        )
        return out

    # --- derived exactly as LEAD's properties ---
    @property
    def target_dataset(self) -> TargetDataset:
        if self.use_waymo_e2e_data:
            return TargetDataset.WAYMO_E2E_2025_3CAMERAS
        if self.use_navsim_data:
            return TargetDataset.NAVSIM_4CAMERAS
        root = self.carla_root
        if any(tag in root for tag in ("carla_leaderboard2", "carla_leaderboad2_v3", "carla_leaderboad2_v8")):
            return TargetDataset.CARLA_LEADERBOARD2_3CAMERAS
        if "carla_leaderboad2_v10" in root:
            return TargetDataset.CARLA_LEADERBOARD2_6CAMERAS
        raise UserError(f"config.json: carla_root={root!r} names no CARLA dataset LEAD knows (carla_leaderboard2 ...)")

    @property
    def mixed_data_training(self) -> bool:
        return int(self.use_navsim_data) + int(self.use_carla_data) + int(self.use_waymo_e2e_data) > 1

    @property
    def carla_leaderboard_mode(self) -> bool:
        carla = self.target_dataset in (
            TargetDataset.CARLA_LEADERBOARD2_3CAMERAS,
            TargetDataset.CARLA_LEADERBOARD2_6CAMERAS,
        )
        return carla and not self.mixed_data_training

    @property
    def num_used_cameras(self) -> int:
        return sum(int(bool(u)) for u in self.used_cameras or ())

    @property
    def is_wod(self) -> bool:
        return self.target_dataset == TargetDataset.WAYMO_E2E_2025_3CAMERAS

    @property
    def min_x_meter(self) -> int:
        return 0 if self.is_wod else -32

    @property
    def max_x_meter(self) -> int:
        return 64 if self.carla_leaderboard_mode or self.is_wod else 32

    @property
    def min_y_meter(self) -> int:
        return -40 if self.carla_leaderboard_mode else -32

    @property
    def max_y_meter(self) -> int:
        return 40 if self.carla_leaderboard_mode else 32

    @property
    def bev_extent(self) -> tuple[tuple[int, int], tuple[int, int]]:
        """Ours: ((min_x, max_x), (min_y, max_y)) of the BEV, metres in LEAD's ego frame."""
        return (self.min_x_meter, self.max_x_meter), (self.min_y_meter, self.max_y_meter)

    @property
    def lidar_width_pixel(self) -> int:
        """BEV columns (ego x, back to front)."""
        return int((self.max_x_meter - self.min_x_meter) * self.pixels_per_meter)

    @property
    def lidar_height_pixel(self) -> int:
        """BEV rows (ego y, left to right)."""
        return int((self.max_y_meter - self.min_y_meter) * self.pixels_per_meter)

    @property
    def lidar_vert_anchors(self) -> int:
        return self.lidar_height_pixel // 32

    @property
    def lidar_horz_anchors(self) -> int:
        return self.lidar_width_pixel // 32

    @property
    def mosaic_tiles(self) -> tuple[int, ...] | None:
        """CARLA: the used camera tiles of the stitched mosaic when LEAD crops some of them (``used_cameras``), else
        None; NAVSIM's cameras are separate images, picked by the data's camera list instead."""
        if not self.carla_leaderboard_mode or all(self.used_cameras):
            return None
        return tuple(i for i, used in enumerate(self.used_cameras) if used)

    @property
    def camera_tile(self) -> tuple[int, int]:
        """(width, height) of one camera tile: the override, else the target's."""
        size = self.camera_tile_size
        return (int(size[0]), int(size[1])) if size is not None else CAMERA_TILE[self.target_dataset]

    @property
    def final_image_width(self) -> int:
        return self.num_used_cameras * self.camera_tile[0]

    @property
    def final_image_height(self) -> int:
        return self.camera_tile[1]

    @property
    def img_vert_anchors(self) -> int:
        return self.final_image_height // 32

    @property
    def img_horz_anchors(self) -> int:
        return self.final_image_width // 32

    @property
    def discrete_command_dim(self) -> int:
        return 6 if self.carla_leaderboard_mode else 4

    @property
    def use_acceleration(self) -> bool:
        return not self.carla_leaderboard_mode and not self.is_wod

    @property
    def max_speed(self) -> float:
        if self.carla_leaderboard_mode:
            return 25.0
        return WOD_MAX_SPEED if self.is_wod else 15.0

    @property
    def max_acceleration(self) -> float | None:
        """None for WOD-E2E, as LEAD's property (no acceleration token there)."""
        if self.carla_leaderboard_mode:
            return 10.0
        return None if self.is_wod else 4.0

    @property
    def use_tp(self) -> bool:
        """The current target point token follows CARLA leaderboard mode (previous and next default to it)."""
        return self.carla_leaderboard_mode

    @property
    def target_point_slots(self) -> tuple[str, ...]:
        """LEAD's input keys of the target points the planner reads, in its token order."""
        used = (self.use_tp, self.use_previous_tp, self.use_next_tp)
        keys = ("target_point", "target_point_previous", "target_point_next")
        return tuple(key for key, use in zip(keys, used, strict=True) if use)

    @property
    def target_points_normalization_constants(self) -> tuple[float, float]:
        return (200.0, 50.0)

    @property
    def predict_target_speed(self) -> bool:
        return self.carla_leaderboard_mode

    @property
    def predict_spatial_path(self) -> bool:
        return self.carla_leaderboard_mode

    @property
    def sources(self) -> tuple[str, ...]:
        """The sources whose batches the network reads: its target (our name), and CARLA when it has CARLA heads."""
        source = "carla" if self.carla_leaderboard_mode else "wod" if self.is_wod else "navsim"
        return (source, "carla") if self.use_carla_data and source != "carla" else (source,)

    def perception_tasks(self, source: str) -> set[str]:
        """Our perception tasks (names of ``lead_s2r.training.loss_table``) LEAD's heads produce for ``source``."""
        heads = {"navsim": self.use_navsim_data, "carla": self.use_carla_data}.get(source, False)
        carla = source == "carla" and self.use_carla_data
        switches = {
            "bev_semantic": heads and self.use_bev_semantic,
            "lead_boxes": heads and self.detect_boxes,
            "semantic": carla and self.use_semantic,
            "depth": carla and self.use_semantic and self.use_depth,
            "radar": source == "carla" and self.has_radar_detector,
        }
        return {task for task, on in switches.items() if on}

    @property
    def has_radar_detector(self) -> bool:
        return bool(self.radar_detection and self.use_carla_data)

    @property
    def planner_radar_tokens(self) -> bool:
        """Whether the planner has radar query tokens; it reads them only with CARLA data (LEAD's TFv6.forward)."""
        return bool(self.use_radars and self.radar_detection and self.use_radar_detection)


def _typed(name: str, value: Any, hint: Any) -> Any:
    """``value`` when it has the JSON type of ``hint`` (an int stands for a float, null for "LEAD's rule decides")."""
    if not fits(value, hint):
        raise UserError(f"config.json: {name} is {value!r}; LEAD writes it as {describe(hint)}")
    kinds = get_args(hint) or (hint,)
    return float(value) if float in kinds and int not in kinds and fits(value, int) else value
