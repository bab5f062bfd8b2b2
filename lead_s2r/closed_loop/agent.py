"""The CARLA leaderboard 2.0 agent for checkpoints of this package: ``--agent=<this file> --agent-config=<run
folder, checkpoint, or a YAML of ClosedLoopConfig fields>``. Usage and command lines: ``docs/closed_loop.md``.

Lifecycle, as leaderboard 2.0 drives it: ``get_entry_point()`` names the class; ``get_ros_version()`` (a static
method: the evaluator calls it on the class) is 0; the evaluator builds ``Agent(host, port, debug)``, calls
``set_global_plan(gps_route, world_route)`` (the leaderboard's base class downsamples it), then ``setup(agent_config)``,
``sensors()``, ``run_step(input_data, timestamp)`` every 50 ms tick and ``destroy()``. Without the leaderboard
installed, a stand-in base class with the same interface is used (it keeps the plan as given), so the package imports
and the tests run without CARLA; the ``carla`` client (``VehicleControl``) is imported when the first control is made.

Per tick: sensors -> a schema sample (:mod:`.sensors`) -> the training transform of the ``carla`` source -> the model
-> LEAD's controllers (:mod:`.controllers`). LEAD reads ``IS_BENCH2DRIVE`` as true whenever it is set, even to 0;
here it is a real boolean (``1/true/yes/on`` or ``0/false/no/off``, anything else is an error).
"""

import json
import logging
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal, get_type_hints

import numpy as np
import torch
import yaml

from lead_s2r.closed_loop.checkpoint import UnsupportedCheckpoint, check_drivable, load_driving_model, rig_for
from lead_s2r.closed_loop.controllers import (
    Control,
    Creeper,
    LateralPID,
    StopSignSlowdown,
    WaypointController,
    decode_target_speed,
    gate,
    throttle_brake,
)
from lead_s2r.closed_loop.route import (
    GeoReference,
    PositionFilter,
    TargetPoints,
    compass_to_yaw,
    estimate_geo_reference,
    gnss_to_world,
    road_option,
)
from lead_s2r.closed_loop.sensors import COMPASS, PoseReading, Rig, build_sample, sensor_specs
from lead_s2r.data.collate import collate
from lead_s2r.data.lead_centernet import CENTERNET_STRIDE
from lead_s2r.data.lead_labels import LeadBoxClass, bev_cell_centres
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.errors import UserError
from lead_s2r.fields import check_fields
from lead_s2r.files import write_text
from lead_s2r.formats.carla_rig import CAMERA_RIGS, EGO_HALF_EXTENT, MOSAIC_ID
from lead_s2r.geometry import CARLA_REAR_AXLE_TO_CENTER, flip_y
from lead_s2r.models.input_spec import InputSpec


class _StandInAgent:
    """leaderboard 2.0's ``AutonomousAgent`` interface, for running without the leaderboard installed."""

    def __init__(self, carla_host: str, carla_port: int, debug: bool = False) -> None:
        self.track = SENSORS_TRACK
        self._global_plan: list | None = None
        self._global_plan_world_coord: list | None = None

    def set_global_plan(self, global_plan_gps: list, global_plan_world_coord: list) -> None:
        self._global_plan, self._global_plan_world_coord = list(global_plan_gps), list(global_plan_world_coord)


try:  # pragma: no cover - depends on the environment
    from leaderboard.autoagents.autonomous_agent import AutonomousAgent, Track

    SENSORS_TRACK: Any = Track.SENSORS
except ImportError:
    AutonomousAgent: Any = _StandInAgent
    SENSORS_TRACK = "SENSORS"

#: The simulator's fixed step (leaderboard ``frame_rate = 20``), seconds.
CARLA_DT = 0.05
#: ``lower_target_speed`` multiplies the predicted target speed by this.
LOWER_TARGET_SPEED_FACTOR = 0.8
#: A stop-sign heatmap peak counts as a sign above this score (our choice; LEAD thresholds its decoded boxes).
STOP_SIGN_SCORE = 0.3
TRUE, FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off", "")
#: The first tick's control, and that of a tick the agent cannot drive on.
BRAKE = Control(0.0, 0.0, 1.0)
logger = logging.getLogger(__name__)


def get_entry_point() -> str:
    return "LeadS2RAgent"


def parse_bool(name: str, value: str) -> bool:
    """A boolean environment value; anything but the usual spellings is an error naming the variable."""
    text = value.strip().lower()
    if text in TRUE:
        return True
    if text in FALSE:
        return False
    raise ValueError(f"environment variable {name}={value!r}: expected one of {', '.join(TRUE + FALSE[:-1])}")


@dataclass
class ClosedLoopConfig:
    """How the agent drives. ``checkpoint``: a ``lead-s2r fit`` run folder or checkpoint file, or a LEAD checkpoint
    folder (config.json + model*.pth; ``pattern`` picks its files, several of them drive as LEAD's ensemble).

    Args:
        source: the model's source whose output grid and label space drive (the CARLA data's source name).
        rig: LEAD camera rig name; None derives it from the model's image size.
        controller: "route" (lateral PID on the predicted route, longitudinal model on the target speed; LEAD's
            default) or "waypoint" (LEAD's waypoint PID).
        use_kalman_filter: filter the GNSS position (filterpy UKF) for the route planners and target points.
        adaptive_pop_distance, skip_distant_target_point, steer_correction: LEAD's sensor-agent defaults (on).
        creeping, stop_sign_slowdown, lower_target_speed: LEAD's test-time heuristics (off).
        bench2drive: Bench2Drive mode (the agent config is cut at the first ``+``; ``metric_info.json`` is written
            when the harness offers ``get_metric_info``); the ``IS_BENCH2DRIVE`` environment variable overrides it.
    """

    checkpoint: str
    pattern: str = "model*.pth"
    source: str = "carla"
    rig: str | None = None
    controller: Literal["route", "waypoint"] = "route"
    use_kalman_filter: bool = True
    adaptive_pop_distance: bool = True
    skip_distant_target_point: bool = True
    steer_correction: bool = True
    creeping: bool = False
    stop_sign_slowdown: bool = False
    lower_target_speed: bool = False
    jpeg_quality: int = 90  # LEAD's jpeg_quality of the closed-loop image round trip
    bench2drive: bool = False
    device: str | None = None

    def __post_init__(self) -> None:
        if self.controller not in ("route", "waypoint"):
            raise ValueError(f"controller must be 'route' or 'waypoint', got {self.controller!r}")
        if self.rig is not None and self.rig not in CAMERA_RIGS:
            raise ValueError(f"rig {self.rig!r} is not a LEAD camera rig; known: {', '.join(CAMERA_RIGS)}")

    @classmethod
    def from_agent_config(cls, agent_config: str, environ: dict[str, str] | None = None) -> "ClosedLoopConfig":
        """Parse the leaderboard's ``--agent-config``: a YAML of these fields, or a checkpoint / run folder."""
        environ = dict(os.environ) if environ is None else environ
        bench2drive = parse_bool("IS_BENCH2DRIVE", environ["IS_BENCH2DRIVE"]) if "IS_BENCH2DRIVE" in environ else None
        if bench2drive:
            agent_config = agent_config.split("+", 1)[0]  # Bench2Drive appends "+<save name>"
        if agent_config.endswith((".yaml", ".yml")):
            config = cls.read(Path(agent_config))
        else:
            config = cls(checkpoint=agent_config)
        if bench2drive is not None:
            config.bench2drive = bench2drive
        return config

    @classmethod
    def read(cls, path: Path) -> "ClosedLoopConfig":
        """An agent config YAML whose every field has its type (``creeping: 7`` would drive as True)."""
        try:
            values = yaml.safe_load(path.read_bytes()) or {}
        except (OSError, yaml.YAMLError) as err:  # YAMLError covers bytes that are not UTF-8
            raise AgentConfigError(f"{path}: cannot read the agent config ({err})") from None
        hints = get_type_hints(cls)
        if not isinstance(values, dict) or set(values) - set(hints) or "checkpoint" not in values:
            unknown = sorted(set(values) - set(hints)) if isinstance(values, dict) else values
            raise AgentConfigError(f"{path}: unknown keys {unknown} or no 'checkpoint'; known: {sorted(hints)}")
        check_fields(values, hints, str(path), AgentConfigError)
        try:
            return cls(**values)
        except ValueError as err:  # its own checks: the controller, the rig
            raise AgentConfigError(f"{path}: {err}") from None

    def write(self, path: Path) -> Path:
        """This config as the YAML :meth:`read` reads (every field, so a run records how it drove)."""
        return write_text(path, yaml.safe_dump(asdict(self), sort_keys=False))


class AgentConfigError(UserError, ValueError):
    """An agent config YAML the agent cannot drive with; the message names the file and the field."""


class LeadS2RAgent(AutonomousAgent):
    """Drives a checkpoint of this package on the SENSORS track (see the module docstring)."""

    @staticmethod
    def get_ros_version() -> int:
        return 0

    def setup(self, path_to_conf_file: str) -> None:
        self.track = SENSORS_TRACK
        self.config = config = ClosedLoopConfig.from_agent_config(path_to_conf_file)
        self.spec = spec = self._load_model(config)
        self.rig = Rig(config.rig or rig_for(spec), lidar=spec.lidar_raster, radar=spec.radar)
        self.transform = SourceTransform(config.source, spec, cameras=[MOSAIC_ID])
        self.classes = tuple(self.model.target_speed_classes.tolist())
        self.lateral = LateralPID(config.steer_correction)
        self.waypoint_controller = WaypointController(spec.trajectory_grids[config.source].dt)
        self.creeper = Creeper(EGO_HALF_EXTENT[0] + CARLA_REAR_AXLE_TO_CENTER, EGO_HALF_EXTENT[1])
        self.stop_sign = StopSignSlowdown()
        self.position_filter = PositionFilter(CARLA_DT) if config.use_kalman_filter else None
        self.navigator: TargetPoints | None = None
        self.reference: GeoReference | None = None
        self.step = 0
        self.last_sample: dict[str, Any] | None = None

    def _load_model(self, config: ClosedLoopConfig) -> InputSpec:
        """The network on its device; what it reads, once it is known to drive with every switch ``config`` sets."""
        device = config.device or ("cuda" if torch.cuda.is_available() else "cpu")
        self.device = torch.device(device)
        self.model, path = load_driving_model(config.checkpoint, config.pattern, device)
        spec = check_drivable(self.model, config.source, path)
        if config.stop_sign_slowdown and spec.lead_box_classes.get(config.source, 0) <= LeadBoxClass.STOP_SIGN:
            raise UnsupportedCheckpoint(
                f"{path}: stop_sign_slowdown needs LEAD's CARLA box head for source {config.source!r}; the model has "
                "none (set stop_sign_slowdown: false)"
            )
        return spec

    def sensors(self) -> list[dict[str, Any]]:
        return sensor_specs(self.rig)

    # ------------------------------------------------------------------ route

    def _start_route(self) -> None:
        """Geo reference and target-point planners from the (downsampled) global plan."""
        if not self._global_plan or not self._global_plan_world_coord:
            raise RuntimeError("run_step before set_global_plan: the agent has no route to follow")
        gnss = np.array([[gps["lat"], gps["lon"]] for gps, _ in self._global_plan])
        world = np.array([[t.location.x, t.location.y] for t, _ in self._global_plan_world_coord])
        self.reference = estimate_geo_reference(gnss, world)
        commands = [road_option(option) for _, option in self._global_plan_world_coord]
        self.navigator = TargetPoints(
            flip_y(world), commands, self.config.adaptive_pop_distance, self.config.skip_distant_target_point
        )

    def pose(self, reading: PoseReading) -> np.ndarray:
        """World ISO (x, y, yaw) of the vehicle centre from GNSS and compass, filtered when configured."""
        xy = flip_y(gnss_to_world(reading.gnss[0], reading.gnss[1], self.reference))
        yaw = compass_to_yaw(float(reading.imu[COMPASS]))
        if self.position_filter is not None:
            xy = self.position_filter.step(np.r_[xy, yaw, reading.speed])[:2]
        return np.r_[xy, yaw]

    def preprocess(
        self, input_data: dict[str, Any], timestamp: float, reading: PoseReading | None = None
    ) -> dict[str, Any]:
        """One tick -> the model's input batch (of one sample), stepping the route state."""
        reading = PoseReading.read(input_data) if reading is None else reading
        if self.navigator is None:
            self._start_route()
        navigation = self.navigator.step(self.pose(reading))
        sample = build_sample(input_data, reading, self.rig, navigation, self.step, timestamp, self.config.jpeg_quality)
        self.last_sample = sample
        return collate([self.transform(sample)])

    # ------------------------------------------------------------------ driving

    @torch.inference_mode()
    def predict(self, batch: dict[str, Any]) -> dict[str, torch.Tensor]:
        tasks = {"waypoints", "route", "target_speed"}
        if self.config.stop_sign_slowdown:
            tasks.add("lead_boxes")
        inputs = {k: v.to(self.device) if isinstance(v, torch.Tensor) else v for k, v in batch.items()}
        return {k: v[0].float().cpu() for k, v in self.model(inputs, self.config.source, tasks).items()}

    def control(self, prediction: dict[str, torch.Tensor], speed: float) -> Control:
        """LEAD's controllers and heuristics on one prediction."""
        if self.config.controller == "waypoint":
            control = self.waypoint_controller.step(prediction["waypoints"].numpy(), speed)
        else:
            target = decode_target_speed(prediction["target_speed_logits"].numpy(), self.classes)
            if self.config.lower_target_speed:
                target *= LOWER_TARGET_SPEED_FACTOR
            throttle, brake = throttle_brake(target, speed)
            control = Control(self.lateral.step(prediction["route"].numpy(), speed), throttle, brake)
        if self.config.creeping:
            control = self.creeper.step(control, speed, self.last_sample.get("lidar"))
        if self.config.stop_sign_slowdown:
            control = self.stop_sign.step(control, speed, self.stop_sign_distance(prediction))
        return gate(control, speed)

    def stop_sign_distance(self, prediction: dict[str, torch.Tensor]) -> float | None:
        """Distance (m) from the front bumper to the strongest predicted stop sign, None when there is none."""
        heatmap = prediction["box_heatmap"][LeadBoxClass.STOP_SIGN].sigmoid()
        if float(heatmap.max()) < STOP_SIGN_SCORE:
            return None
        row, col = np.unravel_index(int(heatmap.argmax()), tuple(heatmap.shape))
        xs, ys = bev_cell_centres(self.spec.bev, CENTERNET_STRIDE)
        # LEAD's CARLA network sees its frame, whose origin is the vehicle centre (lead_s2r.data.lead_origin)
        bumper = EGO_HALF_EXTENT[0] + (0.0 if self.transform.lead_carla else CARLA_REAR_AXLE_TO_CENTER)
        return math.hypot(max(float(xs[row]) - bumper, 0.0), float(ys[col]))

    def run_step(self, input_data: dict[str, Any], timestamp: float) -> Any:
        """One tick: the route state advances; the first tick brakes (LEAD's initial frame delay). A tick whose
        GNSS, IMU or speed is not a number brakes and leaves the route state as it was; so does a prediction that is
        not a number. A sensor missing or misshapen is a :class:`~.sensors.SensorInputError` naming it."""
        reading = PoseReading.read(input_data)
        unusable, control = reading.unusable(), BRAKE
        if unusable is None:
            batch = self.preprocess(input_data, timestamp, reading)
            if self.step > 0:
                prediction = self.predict(batch)
                if all(bool(value.isfinite().all()) for value in prediction.values()):
                    control = self.control(prediction, reading.speed)
                else:
                    unusable = "the model's prediction is not a number"
        if unusable is not None:
            logger.warning("tick %d: %s; braking", self.step, unusable)
        self.step += 1
        if self.config.bench2drive:
            self._write_metric_info()
        return vehicle_control(control)

    def _write_metric_info(self) -> None:
        """Bench2Drive's per-step metric dump, where its harness provides ``get_metric_info``."""
        get_metric_info, save_path = getattr(self, "get_metric_info", None), os.environ.get("SAVE_PATH")
        if get_metric_info is None or not save_path:
            return
        path = Path(save_path) / "metric_info.json"
        info = json.loads(path.read_text()) if path.is_file() else {}
        info[self.step] = get_metric_info()
        write_text(path, json.dumps(info, indent=1))

    def destroy(self) -> None:
        self.model = None
        if torch.cuda.is_available():
            torch.cuda.empty_cache()


def vehicle_control(control: Control) -> Any:
    """A ``carla.VehicleControl`` (the PyPI ``carla`` client: ``pip install 'lead-s2r[carla]'``)."""
    try:
        import carla
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError("the closed-loop agent needs the CARLA client: pip install 'lead-s2r[carla]'") from err
    return carla.VehicleControl(
        steer=float(control.steer), throttle=float(control.throttle), brake=float(control.brake)
    )
