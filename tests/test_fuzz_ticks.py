"""Fuzz of what a driving model receives while it drives: one random damage per trial of a CARLA agent's tick
(``input_data`` as leaderboard 2.0 hands it to ``run_step``) or of an AlpaSim session's messages to ``lead-s2r serve
alpasim`` (real gRPC on loopback).

The contract, per trial. The agent: one line of :class:`SensorInputError` naming the sensor; or a control in range,
the brake (0, 0, 1) where the GNSS, IMU or speedometer gave a value that is not a number or out of range (a NaN
compass excepted: CARLA's first ticks give one, read as north), after which the next pristine tick drives exactly as
if the damaged one had not come (the route state untouched); never another exception. The server: the pristine
trajectory, a changed finite one where the damage leaves a valid value (JPEG bytes that still decode, a finite
number), or INVALID_ARGUMENT / FAILED_PRECONDITION naming the field in one line; never INTERNAL, a non-finite pose
or a call that hangs. ``LEAD_S2R_FUZZ_TRIALS`` sets the trials per target (default 30), ``LEAD_S2R_FUZZ_SEED`` the
seed.
"""

import copy
import io
import math
import os
import uuid
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from corruptions import KINDS, corrupt
from lead_reference import TINY_CARLA

from lead_s2r.closed_loop.agent import LeadS2RAgent
from lead_s2r.closed_loop.check import straight_route, synthetic_input
from lead_s2r.closed_loop.sensors import COMPASS, GNSS_ID, IMU_ID, SPEED_ID, SensorInputError
from lead_s2r.models import lead

TRIALS = int(os.environ.get("LEAD_S2R_FUZZ_TRIALS", "30"))
SEED = int(os.environ.get("LEAD_S2R_FUZZ_SEED", "0"))
TARGETS = ("agent-tick", "alpasim-messages")
#: Damages of one sensor's reading in a tick.
TICK_DAMAGES = ("missing", "not_a_pair", "wrong_type", "wrong_shape", "empty", "nan", "inf", "huge")
#: Readings whose non-finite values make the agent brake; the others' non-finite rows are dropped.
POSE_SENSORS = (GNSS_ID, IMU_ID, SPEED_ID)
BRAKE = (0.0, 0.0, 1.0)
#: Seconds a gRPC call may take before the trial counts as a hang.
CALL_TIMEOUT = 60.0
pytestmark = pytest.mark.usefixtures("one_thread")


# ---------------------------------------------------------------------------------------------------- agent


def damage_reading(value: Any, kind: str, rng: np.random.Generator) -> Any:
    """``value`` (an array, or the speedometer's dict) with one damage of ``kind`` (not missing / not_a_pair)."""
    if isinstance(value, dict):  # the speedometer
        if kind in ("wrong_shape", "empty"):
            return {"velocity": value["speed"]} if kind == "wrong_shape" else {}
        return {"speed": {"nan": math.nan, "inf": -math.inf, "huge": 1e30}.get(kind, "x")}
    array = np.array(value)
    if kind == "wrong_type":
        return [None, "text", {"k": 1}, [1, "a"]][int(rng.integers(4))]
    if kind == "wrong_shape":
        return [array[..., :-1], array.reshape(-1), array[None]][int(rng.integers(3))]
    if kind == "empty":
        return array[:0]
    at = tuple(int(rng.integers(n)) for n in array.shape) if array.size else ()
    if array.dtype == np.uint8:  # a camera: a float image, or garbage pixels
        if kind == "huge":
            return rng.integers(0, 256, array.shape, dtype=np.uint8)
        array = array.astype(np.float32)
    if at:
        array[at] = {"nan": math.nan, "inf": math.inf, "huge": -1e30}[kind]
    return array


def damaged_tick(data: dict, rng: np.random.Generator) -> tuple[dict, str, str]:
    """A copy of ``data`` with one sensor's reading damaged: (tick, sensor id, damage)."""
    damaged = dict(data)
    sensor = sorted(data)[int(rng.integers(len(data)))]
    kind = TICK_DAMAGES[int(rng.integers(len(TICK_DAMAGES)))]
    if kind == "missing":
        del damaged[sensor]
    elif kind == "not_a_pair":
        damaged[sensor] = data[sensor][1]
    else:
        damaged[sensor] = (data[sensor][0], damage_reading(data[sensor][1], kind, rng))
    return damaged, sensor, kind


def may_refuse(sensor: str, kind: str) -> bool:
    """Whether a damage may be a :class:`SensorInputError`: a reading missing, of another type or shape, an empty or
    float camera image, an empty GNSS, IMU or speedometer reading. LiDAR and radar drive on what is left."""
    if kind in ("missing", "not_a_pair", "wrong_type", "wrong_shape"):
        return True
    if sensor.startswith("rgb_"):
        return kind != "huge"  # garbage pixels are an image
    return sensor in POSE_SENSORS and kind == "empty"


def compass_nan(tick: dict, kind: str, sensor: str) -> bool:
    """Whether the damage is a NaN compass, which CARLA gives on its first ticks and the agent reads as north."""
    return kind == "nan" and sensor == IMU_ID and bool(np.isnan(tick[IMU_ID][1][COMPASS]))


def controls(control: Any) -> tuple[float, float, float]:
    return (control.steer, control.throttle, control.brake)


def in_range(values: tuple[float, float, float]) -> bool:
    steer, throttle, brake = values
    return -1.0 <= steer <= 1.0 and 0.0 <= throttle <= 1.0 and 0.0 <= brake <= 1.0


@pytest.fixture(scope="module")
def driving_agent(tmp_path_factory) -> tuple[LeadS2RAgent, list[dict]]:
    """An agent on a tiny LEAD CARLA checkpoint folder (seeded weights), past its braking first tick on a straight
    route, and the pristine ticks that follow."""
    pytest.importorskip("carla", reason="the CARLA client (pip install 'lead-s2r[carla]') builds CARLA's types")
    folder = tmp_path_factory.mktemp("fuzz_ticks") / "lead"
    torch.manual_seed(0)
    lead.export_checkpoint(lead.model_from_config(TINY_CARLA), folder)
    config = folder.parent / "agent.yaml"
    config.write_text(f"checkpoint: {folder}\ndevice: cpu\n")
    agent = LeadS2RAgent("localhost", 2000, False)
    agent.set_global_plan(*straight_route())
    agent.setup(str(config))
    ticks = [synthetic_input(agent.sensors(), frame, np.random.default_rng(frame)) for frame in range(3)]
    agent.run_step(ticks[0], 0.0)
    return agent, ticks[1:]


def agent_trial(made: tuple[LeadS2RAgent, list[dict]], rng: np.random.Generator) -> str:
    """Damage one reading of a tick; the agent drives, brakes or names the sensor, and the next tick drives."""
    base, (tick, after) = made
    agent = copy.deepcopy(base)
    damaged, sensor, kind = damaged_tick(tick, rng)
    what = f"sensor {sensor!r}: {kind}"
    try:
        got = controls(agent.run_step(damaged, 0.05))
    except SensorInputError as err:
        message = str(err)
        assert repr(sensor) in message and "\n" not in message, f"{what}: {message}"
        assert may_refuse(sensor, kind), f"{what}: refused a reading it can drive on: {message}"
        return "sensor error"
    assert all(map(math.isfinite, got)) and in_range(got), f"{what}: control {got}"
    must_brake = kind in ("nan", "inf", "huge") and sensor in POSE_SENSORS and not compass_nan(damaged, kind, sensor)
    braked = got == BRAKE and must_brake
    assert braked or not must_brake, f"{what}: drove on {got}"
    following = controls(agent.run_step(after, 0.1))
    assert all(map(math.isfinite, following)) and in_range(following), f"{what}: then {following}"
    if braked:  # the damaged tick left the route state as it was
        assert following == controls(copy.deepcopy(base).run_step(after, 0.1)), f"{what}: the route state moved"
        return "braked"
    return "drove"


# ---------------------------------------------------------------------------------------------------- AlpaSim

#: Damages of one AlpaSim message: its image's bytes (a corruptions.py kind), its size, a pose, a dynamic state or
#: a route waypoint value, or a timestamp.
MESSAGE_DAMAGES = ("image_bytes", "image_size", "pose", "quaternion", "dynamics", "route", "timestamp")
BAD_NUMBERS = (math.nan, math.inf, -math.inf, 1e300, -1e30)


@pytest.fixture(scope="module")
def alpasim_server(tmp_path_factory) -> Iterator[tuple[str, Path]]:
    """``serve alpasim`` on loopback over LEAD's golden tiny NAVSIM folder; and a scratch folder."""
    pytest.importorskip("carla_driver_interface", reason="the AlpaSim extra: pip install 'lead-s2r[alpasim]'")
    from test_alpasim import LEAD_FOLDER, running

    from lead_s2r.closed_loop.alpasim_model import load_served_model

    scratch = tmp_path_factory.mktemp("fuzz_alpasim")
    for target in running(load_served_model(LEAD_FOLDER, None, "model*.pth", "cpu")):
        yield target, scratch


class Messages:
    """One AlpaSim step of a fresh session, as its runtime sends it, each message open to one damage before it goes."""

    def __init__(self) -> None:
        from carla_driver_interface import protocol
        from carla_driver_interface.geometry import Pose, waypoints_to_proto
        from carla_driver_interface.testing import FakeCamera, render_road
        from PIL import Image

        self.protocol, self.session, self.now_us = protocol, str(uuid.uuid4()), 1_000_000
        self.camera = FakeCamera("camera_front", width=480, height=270, fov_deg=63.7)
        start = protocol.DriveSessionRequest(session_uuid=self.session)
        start.rollout_spec.vehicle.available_cameras.append(self.camera.available_camera())
        self.start = start
        self.egomotion = protocol.RolloutEgoTrajectory(session_uuid=self.session)
        for step in range(3):
            at = self.now_us - (2 - step) * 100_000
            self.egomotion.trajectory.poses.append(Pose.from_xyz_yaw(0.5 * step, 0.0, 0.0, 0.0).to_proto_at_time(at))
            self.egomotion.dynamic_states.add().linear_velocity.x = 5.0
        route = np.array([[x, 0.0, 0.0] for x in np.arange(2.0, 40.0, 2.0)])
        self.route = protocol.RouteRequest(
            session_uuid=self.session,
            route=protocol.Route(timestamp_us=self.now_us, waypoints=waypoints_to_proto(route)),
        )
        buffer = io.BytesIO()
        self.rendered = Image.fromarray(render_road(self.camera, Pose.identity()))
        self.rendered.save(buffer, format="JPEG")
        self.image = protocol.RolloutCameraImage(session_uuid=self.session)
        self.image.camera_image.logical_id, self.image.camera_image.frame_end_us = "camera_front", self.now_us
        self.image.camera_image.image_bytes = buffer.getvalue()
        self.drive = protocol.DriveRequest(session_uuid=self.session, time_now_us=self.now_us)

    def damage(self, kind: str, scratch: Path, rng: np.random.Generator) -> str:
        """One damage of ``kind``; says what it did."""
        bad = BAD_NUMBERS[int(rng.integers(len(BAD_NUMBERS)))]
        if kind == "image_bytes":
            path = scratch / f"{self.session}.jpg"
            path.write_bytes(self.image.camera_image.image_bytes)
            what = corrupt(path, KINDS[int(rng.integers(len(KINDS)))], rng)
            self.image.camera_image.image_bytes = path.read_bytes() if path.exists() else b""
            return f"image bytes: {what}"
        if kind == "image_size":
            scale = float(rng.choice([0.25, 0.5, 2.0]))
            size = (round(self.rendered.width * scale), round(self.rendered.height * rng.choice([scale, 1.0])))
            buffer = io.BytesIO()
            self.rendered.resize(size).save(buffer, format="JPEG")
            self.image.camera_image.image_bytes = buffer.getvalue()
            return f"image of {size[0]}x{size[1]} for a {self.rendered.width}x{self.rendered.height} camera"
        if kind in ("pose", "quaternion"):
            pose = self.egomotion.trajectory.poses[int(rng.integers(3))].pose
            if kind == "quaternion":
                pose.quat.x = pose.quat.y = pose.quat.z = pose.quat.w = 0.0
                return "a zero quaternion"
            axis = ("x", "y", "z")[int(rng.integers(3))]
            setattr(pose.vec, axis, bad)
            return f"pose vec.{axis} = {bad}"
        if kind == "dynamics":
            state = self.egomotion.dynamic_states[int(rng.integers(3))]
            part = ("linear_velocity", "linear_acceleration", "angular_velocity")[int(rng.integers(3))]
            setattr(getattr(state, part), "xyz"[int(rng.integers(3))], bad)
            return f"dynamic state {part} = {bad}"
        if kind == "route":
            point = self.route.route.waypoints[int(rng.integers(len(self.route.route.waypoints)))]
            point.y = bad
            return f"route waypoint y = {bad}"
        self.drive.time_now_us = int(rng.choice([0, 5, self.now_us - 200_000]))
        return f"drive at {self.drive.time_now_us} us, before the last pose at {self.now_us} us"

    def send(self, stub: Any) -> Any:
        stub.start_session(self.start, timeout=CALL_TIMEOUT)
        stub.submit_egomotion_observation(self.egomotion, timeout=CALL_TIMEOUT)
        stub.submit_route(self.route, timeout=CALL_TIMEOUT)
        stub.submit_image_observation(self.image, timeout=CALL_TIMEOUT)
        return stub.drive(self.drive, timeout=CALL_TIMEOUT)


def trajectory(response: Any) -> list[list[float]]:
    """Each pose of a drive response: its time and values."""
    return [
        [p.timestamp_us, p.pose.vec.x, p.pose.vec.y, p.pose.vec.z, p.pose.quat.x, p.pose.quat.y, p.pose.quat.z,
         p.pose.quat.w]
        for p in response.trajectory.poses
    ]  # fmt: skip


def alpasim_trial(made: tuple[str, Path], expected: list, rng: np.random.Generator) -> str:
    import grpc
    from carla_driver_interface import protocol

    target, scratch = made
    stub = protocol.EgodriverServiceStub(grpc.insecure_channel(target))
    messages = Messages()
    kind = MESSAGE_DAMAGES[int(rng.integers(len(MESSAGE_DAMAGES)))]
    what = messages.damage(kind, scratch, rng)
    try:
        got = trajectory(messages.send(stub))
    except grpc.RpcError as err:
        codes = (grpc.StatusCode.INVALID_ARGUMENT, grpc.StatusCode.FAILED_PRECONDITION)
        message = err.details() or ""
        assert err.code() in codes and "\n" not in message and ":" in message, f"{what}: {err.code()} {message}"
        return "refused"
    assert np.isfinite(got).all(), f"{what}: a trajectory that is not finite"
    if got == expected:
        return "same"
    assert kind == "image_bytes", f"{what}: a different trajectory"  # bytes that still decode: another image
    return "changed"


# ---------------------------------------------------------------------------------------------------- the test


@pytest.mark.parametrize("target", TARGETS)
def test_every_damage_keeps_the_contract(target: str, request: pytest.FixtureRequest) -> None:
    rng = np.random.default_rng([SEED, TARGETS.index(target)])
    outcomes: Counter[str] = Counter()
    run: Callable[[], str]
    if target == "agent-tick":
        made = request.getfixturevalue("driving_agent")
        run = lambda: agent_trial(made, rng)  # noqa: E731
    else:
        import grpc
        from carla_driver_interface import protocol

        server = request.getfixturevalue("alpasim_server")
        expected = trajectory(Messages().send(protocol.EgodriverServiceStub(grpc.insecure_channel(server[0]))))
        run = lambda: alpasim_trial(server, expected, rng)  # noqa: E731
    for _ in range(TRIALS):
        outcomes[run()] += 1
    print(target, dict(outcomes))
