"""``lead-s2r serve alpasim`` over real gRPC on loopback: AlpaSim's runtime played by carla-driver-interface's
FakeLoop against a tiny run trained here and against LEAD's golden tiny checkpoint folder; the service's trajectories
held against ``lead-s2r predict`` on converted NAVSIM samples; every client mistake a status naming its field while
other sessions drive on; the container's entry point run as it is written."""

import json
import math
import os
import shutil
import socket
import subprocess
import sys
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import grpc
import numpy as np
import pytest
import torch
import yaml

from lead_s2r.cli import main as cli_main
from lead_s2r.closed_loop.alpasim import serve
from lead_s2r.closed_loop.alpasim_messages import SceneCamera, match_cameras, route_command
from lead_s2r.closed_loop.alpasim_model import CameraSlot, ServedModel, load_served_model
from lead_s2r.convert import convert
from lead_s2r.errors import UserError
from lead_s2r.geometry import wrap_angle
from lead_s2r.models import lead
from lead_s2r.predictions import read_predictions
from lead_s2r.schema import Command
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim as synth
from lead_s2r.training.cli import run_lightning_cli
from lead_s2r_adapters.navsim import NavsimAdapter

pytest.importorskip("carla_driver_interface", reason="the AlpaSim extra: pip install 'lead-s2r[alpasim]'")
from carla_driver_interface import protocol
from carla_driver_interface.geometry import Pose, Trajectory, waypoints_to_proto
from carla_driver_interface.testing import FakeCamera, FakeLoop

pytestmark = pytest.mark.usefixtures("one_thread")

ROOT = Path(__file__).parent.parent
LEAD_FOLDER = ROOT / "tests" / "data" / "lead_tfv6" / "tiny_ltfv6_navsim"
DOCKERFILE = ROOT / "docker" / "alpasim" / "Dockerfile"
STEPS = 20
#: The tiny run's cameras, as nuPlan mounts them: id, yaw (deg), and a name AlpaSim's rigs could give it.
RUN_CAMERAS = (("front_left", 55.0, "camera_cross_left_120fov"), ("front", 0.0, "camera_front_wide_120fov"),
               ("front_right", -55.0, "camera_cross_right_120fov"))  # fmt: skip
#: A tiny LEAD LTFv6 on NAVSIM's three front cameras (LEAD's field names), trained here for two steps.
RUN_MODEL = {
    "use_navsim_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True,
    "use_mixed_precision_training": False, "used_cameras": [True, True, True, False],
    "image_architecture": "test_convnext", "lidar_architecture": "test_resnet", "camera_tile_size": [64, 32],
    "n_layer": 1, "pixels_per_meter": 2.0, "bev_features_chanels": 16, "bb_input_channel": 16,
    "transfuser_token_dim": 32, "transfuser_num_bev_cross_attention_layers": 2,
    "transfuser_num_bev_cross_attention_heads": 4,
}  # fmt: skip


# ---------------------------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def navsim_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("alpasim_navsim")
    synth.generate(root / "raw", count=1)
    assert convert(NavsimAdapter(), root / "raw", root / "data").ok
    return root / "data"


@pytest.fixture(scope="module")
def run(navsim_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run of ours (`lead-s2r fit`, two steps) and its `lead-s2r predict` output beside it (predictions.parquet)."""
    root = tmp_path_factory.mktemp("alpasim_run")
    cameras = [camera for camera, _, _ in RUN_CAMERAS]
    config = {
        "seed_everything": 0,
        "trainer": {
            "accelerator": "cpu", "max_epochs": 1, "logger": False, "enable_progress_bar": False,
            "enable_model_summary": False, "default_root_dir": str(root),
            "callbacks": [{"class_path": "lightning.pytorch.callbacks.ModelCheckpoint",
                           "init_args": {"dirpath": str(root / "checkpoints"), "save_last": True}}],
        },
        "model": {
            "model": {"class_path": "lead_s2r.models.lead_driver.LeadDriver", "init_args": {"config": RUN_MODEL}},
            "supervise": {"navsim": ["planning"]},
        },
        "data": {
            "train": {"navsim": {"paths": [str(navsim_data)], "cameras": cameras}},
            "predict": {"navsim": {"paths": [str(navsim_data)], "cameras": cameras}},
            "schedule": {"anchors": {0: {"navsim": 2}}, "global_batch_size": 2},
            "steps_per_epoch": 2, "eval_batch_size": 4, "shuffle_buffer": 4,
        },
    }  # fmt: skip
    path = root / "fit.yaml"
    path.write_text(yaml.safe_dump(json.loads(json.dumps(config))))
    run_lightning_cli(["fit", "--config", str(path)])
    writer = "lead_s2r.training.prediction_writer.PredictionWriter"
    output = f"--trainer.callbacks.output={root / 'predictions.parquet'}"
    checkpoint = str(root / "checkpoints" / "last.ckpt")
    run_lightning_cli(
        ["predict", "--config", str(path), "--ckpt_path", checkpoint, f"--trainer.callbacks+={writer}", output]
    )
    return root


def running(served: ServedModel) -> Iterator[str]:
    server, port = serve(served, "127.0.0.1", 0)
    try:
        yield f"127.0.0.1:{port}"
    finally:
        server.stop(0).wait()


@pytest.fixture(scope="module")
def lead_server() -> Iterator[str]:
    yield from running(load_served_model(LEAD_FOLDER, None, "model*.pth", "cpu"))


@pytest.fixture(scope="module")
def run_server(run: Path) -> Iterator[str]:
    yield from running(load_served_model(run, None, "model*.pth", "cpu"))


class DriveRecorder(grpc.UnaryUnaryClientInterceptor):
    """Keeps every ``drive`` request and response FakeLoop exchanges."""

    def __init__(self) -> None:
        self.drives: list[tuple[object, object]] = []

    def intercept_unary_unary(self, continuation: Callable, client_call_details: Any, request: Any) -> Any:
        outcome = continuation(client_call_details, request)
        if client_call_details.method.endswith("/drive"):
            self.drives.append((request, outcome.result()))
        return outcome


def in_rig(response: object) -> tuple[np.ndarray, np.ndarray]:
    """A drive response's poses after its first (the anchor), as (x, y, yaw) in the anchor's rig frame, and their
    offsets from the anchor's time (s)."""
    trajectory = Trajectory.from_proto(response.trajectory)
    anchor = trajectory.poses[0].inverse()
    rows = [[*(anchor @ pose).position[:2], (anchor @ pose).yaw] for pose in trajectory.poses[1:]]
    times = (np.asarray(trajectory.timestamps_us[1:]) - trajectory.timestamps_us[0]) / 1e6
    return np.array(rows), times


def drive_fake_loop(target: str, cameras: tuple[FakeCamera, ...], horizon: tuple[int, float]) -> None:
    """FakeLoop for :data:`STEPS` steps; every drive answers the model's horizon, anchored at the ego pose."""
    recorder = DriveRecorder()
    channel = grpc.intercept_channel(grpc.insecure_channel(target), recorder)
    with FakeLoop(channel, cameras, initial_speed_mps=5.0) as loop:
        result = loop.run(STEPS)
    channel.close()
    assert result.steps == STEPS and not result.terminated_by_policy
    points, dt = horizon
    for request, response in recorder.drives:
        assert response.trajectory.poses[0].timestamp_us == request.time_now_us
        plan, times = in_rig(response)
        np.testing.assert_allclose(times, dt * np.arange(1, points + 1))
        assert plan.shape == (points, 3) and np.isfinite(plan).all()
    assert len(result.ego) == STEPS and np.isfinite(result.ego.positions).all()  # the ego followed every plan


# ---------------------------------------------------------------------------------------------------- driving


def test_fakeloop_drives_leads_golden_tiny_checkpoint_folder_for_20_steps(lead_server: str) -> None:
    camera = FakeCamera("camera_front_wide_120fov", width=480, height=270, fov_deg=63.7, x=1.7, z=1.5)
    drive_fake_loop(lead_server, (camera,), (8, 0.5))


def test_fakeloop_drives_a_run_of_ours_with_cameras_matched_by_pose_not_name(run_server: str) -> None:
    # the names lie (the left camera is called "front"...) and the order is shuffled: only the poses say who is who
    cameras = tuple(
        FakeCamera(name, width=192, height=108, fov_deg=63.7, yaw_left_deg=yaw)
        for (_, yaw, _), name in zip(RUN_CAMERAS, ("front", "left", "CAM_F0"), strict=True)
    )
    drive_fake_loop(run_server, cameras[::-1], (8, 0.5))


def test_sessions_drive_at_once_each_with_its_own_state(lead_server: str) -> None:
    camera = FakeCamera("camera_front", width=480, height=270, fov_deg=63.7)

    def loop(offset: float) -> tuple[np.ndarray, np.ndarray]:
        """The session's ego positions and the positions its answers were anchored at."""
        recorder = DriveRecorder()
        channel = grpc.intercept_channel(grpc.insecure_channel(lead_server), recorder)
        with FakeLoop(channel, (camera,), initial_lateral_offset_m=offset, initial_speed_mps=5.0) as fake:
            ego = fake.run(10).ego.positions
        channel.close()
        anchors = [Trajectory.from_proto(response.trajectory).poses[0].position for _, response in recorder.drives]
        return ego, np.array(anchors)

    with ThreadPoolExecutor(3) as pool:
        results = list(pool.map(loop, (0.0, 1.5, -1.5)))
    for (ego, anchors), offset in zip(results, (0.0, 1.5, -1.5), strict=True):
        assert len(ego) == 10 and ego[0, 1] == offset
        np.testing.assert_allclose(anchors, ego, atol=1e-5)  # every answer planned from this session's own ego


def test_camera_matching_follows_direction_and_field_of_view() -> None:
    slots = (CameraSlot("front_left", 55.0, 63.71), CameraSlot("front", 0.0, 63.71))
    cameras = [
        SceneCamera("camera_front", {}, -50.0, 63.0),  # named front, looks right
        SceneCamera("camera_tele", {}, 2.0, 20.0),  # looks forward, but a telephoto
        SceneCamera("a", {}, 3.0, 70.0),
        SceneCamera("b", {}, 50.0, 90.0),
    ]
    assert match_cameras(slots, cameras) == {"b": "front_left", "a": "front"}
    assert route_command(np.array([[1.0, 0.0], [6.0, 2.5]])) == Command.LEFT
    assert route_command(np.array([[6.0, -2.5]])) == Command.RIGHT
    assert route_command(np.array([[6.0, 1.0]])) == Command.STRAIGHT


def test_service_trajectories_equal_lead_s2r_predict_on_converted_navsim_samples(run: Path, run_server: str) -> None:
    """Each converted sample replayed as AlpaSim messages (its cameras with their calibration, its past as egomotion,
    a route that turns as its command says) gives the trajectory `lead-s2r predict` wrote for it."""
    predicted = {p.key: p for p in read_predictions(run / "predictions.parquet")}
    stub = protocol.EgodriverServiceStub(grpc.insecure_channel(run_server))
    samples = list(read_samples(navsim_folder(run)))
    assert len(samples) == len(predicted) >= 5
    for sample in samples:
        plan, times = in_rig(replay(stub, sample))
        expected = predicted[sample["__key__"]]
        np.testing.assert_allclose(times, expected.t, atol=1e-6)
        np.testing.assert_allclose(plan[:, :2], expected.xy, atol=1e-5)
        np.testing.assert_allclose(wrap_angle(plan[:, 2] - expected.yaw), 0.0, atol=1e-5)  # a quaternion wraps yaw


def navsim_folder(run: Path) -> Path:
    config = yaml.safe_load((run / "fit.yaml").read_text())
    return Path(config["data"]["predict"]["navsim"]["paths"][0])


def optical_pose(cam_to_ego: list[list[float]]) -> Pose:
    from scipy.spatial.transform import Rotation

    matrix = np.asarray(cam_to_ego)
    return Pose(matrix[:3, 3], Rotation.from_matrix(matrix[:3, :3]).as_quat())


def replay(stub: protocol.EgodriverServiceStub, sample: dict) -> object:
    """One converted sample sent the way AlpaSim's runtime sends a step; the drive response."""
    meta, session = sample["meta"], str(uuid.uuid4())
    names = {camera: native for camera, _, native in RUN_CAMERAS}
    request = protocol.DriveSessionRequest(session_uuid=session)
    for camera in meta["cameras"]:
        if camera["id"] not in names:
            continue
        (fx, _, cx), (_, fy, cy), _ = camera["K"]
        spec = protocol.CameraSpec(
            opencv_pinhole_param=protocol.OpenCVPinholeCameraParam(
                principal_point_x=cx, principal_point_y=cy, focal_length_x=fx, focal_length_y=fy
            ),
            logical_id=names[camera["id"]], resolution_w=camera["width"], resolution_h=camera["height"],
        )  # fmt: skip
        request.rollout_spec.vehicle.available_cameras.add(
            intrinsics=spec, rig_to_camera=optical_pose(camera["cam_to_ego"]).to_proto(), logical_id=names[camera["id"]]
        )
    stub.start_session(request)
    now_us = 10_000_000
    ego = meta["ego"]
    egomotion = protocol.RolloutEgoTrajectory(session_uuid=session)
    for t, x, y, yaw in sample["past"]:
        egomotion.trajectory.poses.append(Pose.from_xyz_yaw(x, y, 0.0, yaw).to_proto_at_time(now_us + round(t * 1e6)))
        state = egomotion.dynamic_states.add()
        state.linear_velocity.x, state.linear_velocity.y = ego["velocity"]
        state.linear_acceleration.x, state.linear_acceleration.y = ego["acceleration"]
    stub.submit_egomotion_observation(egomotion)
    lateral = {Command.LEFT: 10.0, Command.RIGHT: -10.0}.get(Command(ego["command"]), 0.0)
    route = np.array([[x, lateral * min(x / 20, 1.0), 0.0] for x in np.arange(2.0, 60.0, 2.0)])
    stub.submit_route(protocol.RouteRequest(session_uuid=session, route=protocol.Route(
        timestamp_us=now_us, waypoints=waypoints_to_proto(route))))  # fmt: skip
    for camera, native in names.items():
        image = protocol.RolloutCameraImage(session_uuid=session)
        image.camera_image.logical_id, image.camera_image.frame_end_us = native, now_us
        image.camera_image.image_bytes = sample[f"cam_{camera}"]
        stub.submit_image_observation(image)
    response = stub.drive(protocol.DriveRequest(session_uuid=session, time_now_us=now_us, time_query_us=now_us))
    stub.close_session(protocol.DriveSessionCloseRequest(session_uuid=session))
    return response


# ---------------------------------------------------------------------------------------------------- mistakes


class Client:
    """A minimal AlpaSim runtime on the golden LEAD folder's one front camera, step by step."""

    def __init__(self, target: str) -> None:
        self.stub = protocol.EgodriverServiceStub(grpc.insecure_channel(target))
        self.camera = FakeCamera("camera_front", width=480, height=270, fov_deg=63.7)
        self.session = str(uuid.uuid4())
        self.now_us = 0

    def start(self, cameras: tuple[FakeCamera, ...] | None = None) -> "Client":
        request = protocol.DriveSessionRequest(session_uuid=self.session)
        for camera in (self.camera,) if cameras is None else cameras:
            request.rollout_spec.vehicle.available_cameras.append(camera.available_camera())
        self.stub.start_session(request)
        return self

    def egomotion(self, pose: Pose, timestamp_us: int) -> None:
        message = protocol.RolloutEgoTrajectory(session_uuid=self.session)
        message.trajectory.poses.append(pose.to_proto_at_time(timestamp_us))
        message.dynamic_states.add().linear_velocity.x = 5.0
        self.stub.submit_egomotion_observation(message)

    def image(self, data: bytes, timestamp_us: int) -> None:
        from carla_driver_interface.testing import render_road
        from PIL import Image

        if not data:
            import io

            buffer = io.BytesIO()
            Image.fromarray(render_road(self.camera, Pose.identity())).save(buffer, format="JPEG")
            data = buffer.getvalue()
        message = protocol.RolloutCameraImage(session_uuid=self.session)
        message.camera_image.logical_id, message.camera_image.frame_end_us = self.camera.logical_id, timestamp_us
        message.camera_image.image_bytes = data
        self.stub.submit_image_observation(message)

    def step(self) -> object:
        """One well-formed step: egomotion, image, drive."""
        self.now_us += 100_000
        self.egomotion(Pose.from_xyz_yaw(0.5 * self.now_us / 1e5, 0.0, 0.0, 0.0), self.now_us)
        self.image(b"", self.now_us)
        return self.stub.drive(protocol.DriveRequest(session_uuid=self.session, time_now_us=self.now_us))


def refused(call: Callable[[], object], code: grpc.StatusCode, field: str) -> str:
    with pytest.raises(grpc.RpcError) as info:
        call()
    assert info.value.code() == code, info.value.details()
    message = info.value.details()
    assert field in message and "\n" not in message
    return message


@pytest.fixture
def bystander(lead_server: str) -> Iterator[Client]:
    """A second session, driving before and after each mistake of another."""
    client = Client(lead_server).start()
    client.step()
    yield client
    assert len(in_rig(client.step())[0]) == 8  # unaffected by the other session's error


def test_a_camera_the_model_needs_but_the_scene_lacks_is_failed_precondition(lead_server: str, bystander) -> None:
    rear = FakeCamera("camera_front", width=480, height=270, fov_deg=63.7, yaw_left_deg=180.0)
    message = refused(lambda: Client(lead_server).start((rear,)), grpc.StatusCode.FAILED_PRECONDITION,
                      "rollout_spec.vehicle.available_cameras")  # fmt: skip
    assert "front camera" in message and "camera_front (180 deg" in message
    message = refused(lambda: Client(lead_server).start(()), grpc.StatusCode.FAILED_PRECONDITION,
                      "rollout_spec.vehicle.available_cameras")  # fmt: skip
    assert "(cameras: none)" in message
    client = Client(lead_server)
    request = protocol.DriveSessionRequest(session_uuid=client.session)
    request.rollout_spec.vehicle.available_cameras.append(client.camera.available_camera())
    request.rollout_spec.vehicle.available_cameras[0].intrinsics.ftheta_param.SetInParent()  # the front one, f-theta
    message = refused(lambda: client.stub.start_session(request), grpc.StatusCode.FAILED_PRECONDITION,
                      "rollout_spec.vehicle.available_cameras")  # fmt: skip
    assert "camera_front (not a pinhole camera)" in message


def test_unknown_session_is_not_found(lead_server: str, bystander) -> None:
    ghost = Client(lead_server)
    refused(ghost.step, grpc.StatusCode.NOT_FOUND, "session_uuid")
    refused(lambda: ghost.stub.close_session(protocol.DriveSessionCloseRequest(session_uuid="x")),
            grpc.StatusCode.NOT_FOUND, "session_uuid")  # fmt: skip


def test_out_of_order_timestamps_are_invalid_argument(lead_server: str, bystander) -> None:
    client = Client(lead_server).start()
    client.step()
    refused(lambda: client.egomotion(Pose.identity(), 50_000), grpc.StatusCode.INVALID_ARGUMENT,
            "trajectory.poses[0].timestamp_us")  # fmt: skip
    client.egomotion(Pose.from_xyz_yaw(0.5, 0.0, 0.0, 0.0), client.now_us)  # history sent again: accepted
    refused(lambda: client.image(b"", 50_000), grpc.StatusCode.INVALID_ARGUMENT, "camera_image.frame_end_us")
    refused(lambda: client.stub.drive(protocol.DriveRequest(session_uuid=client.session, time_now_us=50_000)),
            grpc.StatusCode.INVALID_ARGUMENT, "time_now_us")  # fmt: skip
    assert len(in_rig(client.step())[0]) == 8  # the session itself goes on


def test_an_undecodable_image_is_invalid_argument(lead_server: str, bystander) -> None:
    import io

    from carla_driver_interface.testing import render_road
    from PIL import Image

    client = Client(lead_server).start()
    buffer = io.BytesIO()
    Image.fromarray(render_road(client.camera, Pose.identity())).save(buffer, format="JPEG")
    middle = len(buffer.getvalue()) // 2  # a marker inside the scan: OpenCV decodes through it, the model's decoder not
    damaged = buffer.getvalue()[:middle] + b"\xff\x04" + buffer.getvalue()[middle + 2 :]
    for data in (b"\xff\xd8 not a jpeg", b"\x89PNG\r\n", damaged):
        refused(lambda d=data: client.image(d, 1), grpc.StatusCode.INVALID_ARGUMENT, "camera_image.image_bytes")


def test_a_nan_pose_is_invalid_argument(lead_server: str, bystander) -> None:
    client = Client(lead_server).start()
    message = protocol.RolloutEgoTrajectory(session_uuid=client.session)
    message.trajectory.poses.add(timestamp_us=1).pose.vec.x = math.nan
    message.trajectory.poses[0].pose.quat.w = 1.0
    refused(lambda: client.stub.submit_egomotion_observation(message), grpc.StatusCode.INVALID_ARGUMENT,
            "trajectory.poses[0].pose")  # fmt: skip


def test_an_image_of_another_size_than_declared_is_invalid_argument(lead_server: str, bystander) -> None:
    import io

    from carla_driver_interface.testing import render_road
    from PIL import Image

    client = Client(lead_server).start()
    buffer = io.BytesIO()
    Image.fromarray(render_road(client.camera, Pose.identity())).resize((240, 135)).save(buffer, format="JPEG")
    message = refused(lambda: client.image(buffer.getvalue(), 1), grpc.StatusCode.INVALID_ARGUMENT,
                      "camera_image.image_bytes")  # fmt: skip
    assert "240x135 pixels, but the camera is declared 480x270" in message


def test_a_dynamic_state_or_route_out_of_range_and_a_drive_before_the_pose_are_invalid_argument(
    lead_server: str, bystander
) -> None:
    client = Client(lead_server).start()
    message = protocol.RolloutEgoTrajectory(session_uuid=client.session)
    message.trajectory.poses.append(Pose.identity().to_proto_at_time(1))
    message.dynamic_states.add().linear_acceleration.y = math.inf
    refused(lambda: client.stub.submit_egomotion_observation(message), grpc.StatusCode.INVALID_ARGUMENT,
            "dynamic_states[0].linear_acceleration")  # fmt: skip
    route = protocol.RouteRequest(session_uuid=client.session, route=protocol.Route(
        timestamp_us=1, waypoints=waypoints_to_proto(np.array([[1e9, 0.0, 0.0]]))))  # fmt: skip
    refused(lambda: client.stub.submit_route(route), grpc.StatusCode.INVALID_ARGUMENT, "route.waypoints")
    client.egomotion(Pose.identity(), 200_000)
    client.image(b"", 200_000)
    refused(lambda: client.stub.drive(protocol.DriveRequest(session_uuid=client.session, time_now_us=100_000)),
            grpc.StatusCode.INVALID_ARGUMENT, "time_now_us")  # fmt: skip


def test_drive_before_observations_is_failed_precondition(lead_server: str, bystander) -> None:
    client = Client(lead_server).start()
    drive = protocol.DriveRequest(session_uuid=client.session, time_now_us=1)
    refused(lambda: client.stub.drive(drive), grpc.StatusCode.FAILED_PRECONDITION, "egomotion")
    client.egomotion(Pose.identity(), 1)
    drive.time_now_us = 2
    refused(lambda: client.stub.drive(drive), grpc.StatusCode.FAILED_PRECONDITION, "camera_front")


def test_get_version_says_ours(lead_server: str) -> None:
    stub = protocol.EgodriverServiceStub(grpc.insecure_channel(lead_server))
    version = stub.get_version(protocol.Empty())
    assert version.version_id.startswith("lead-s2r ") and "tiny_ltfv6_navsim" in version.version_id


# ---------------------------------------------------------------------------------------------------- the command


def test_serving_a_missing_folder_is_a_user_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert cli_main(["serve", "alpasim", str(tmp_path / "nothing"), "--port", "0"]) == 2
    assert "error:" in capsys.readouterr().err
    with pytest.raises(UserError, match="--source 'carla'"):
        load_served_model(LEAD_FOLDER, "carla", "model*.pth", "cpu")


def test_a_model_reading_sensors_alpasim_lacks_is_refused_and_an_ensemble_serves(tmp_path: Path) -> None:
    from lead_reference import TINY_CARLA

    lead.export_checkpoint(lead.model_from_config(TINY_CARLA), tmp_path / "carla")
    with pytest.raises(UserError, match="reads LiDAR, which AlpaSim"):
        load_served_model(tmp_path / "carla", None, "model*.pth", "cpu")
    ensemble = tmp_path / "ensemble"
    shutil.copytree(LEAD_FOLDER, ensemble)
    shutil.copy(ensemble / "model_0000.pth", ensemble / "model_0001.pth")
    served = load_served_model(ensemble, None, "model*.pth", "cpu")
    assert isinstance(served.model.network, lead.LeadEnsemble)
    target = running(served)
    client = Client(next(target)).start()
    assert all(len(in_rig(client.step())[0]) == 8 for _ in range(3))
    target.close()


def test_a_model_without_cameras_is_refused(tmp_path: Path) -> None:
    """The ego-status MLP reads no camera, and cameras are what AlpaSim provides: a user error at start."""
    from lightning.pytorch.cli import instantiate_module

    from lead_s2r.training.module import DrivingModule

    arguments = {"model": {"class_path": "lead_s2r.models.ego_mlp.EgoStatusMLP", "init_args": {}}}
    module = instantiate_module(DrivingModule, {**arguments, "init_from": None, "compile": False})
    torch.save({"hyper_parameters": arguments, "state_dict": module.state_dict()}, tmp_path / "ego_mlp.ckpt")
    with pytest.raises(UserError, match=r"EgoStatusMLP is not a TransFuser-family model .* from AlpaSim's cameras"):
        load_served_model(tmp_path / "ego_mlp.ckpt", None, "model*.pth", "cpu")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_the_container_entry_point_serves_from_a_read_only_model_folder(tmp_path: Path) -> None:
    """The Dockerfile's ENTRYPOINT + CMD, run here as written: the challenge's environment, the model folder read
    only, HOME and the caches in the temporary folder; it serves, and writes nothing but there."""
    lines = DOCKERFILE.read_text().splitlines()
    entry = json.loads(next(line for line in lines if line.startswith("ENTRYPOINT "))[len("ENTRYPOINT ") :])
    default = json.loads(next(line for line in lines if line.startswith("CMD "))[len("CMD ") :])
    model = tmp_path / "model"
    shutil.copytree(LEAD_FOLDER, model)
    for path in (model, *model.iterdir()):
        path.chmod(0o555 if path.is_dir() else 0o444)
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    port = free_port()
    env = {**os.environ, "ALPASIM_DRIVER_HOST": "127.0.0.1", "ALPASIM_DRIVER_PORT": str(port), "TMPDIR": str(scratch),
           "HOME": str(scratch), "XDG_CACHE_HOME": str(scratch / ".cache"), "TORCH_HOME": str(scratch / "torch"),
           "MPLCONFIGDIR": str(scratch / "mpl"), "CUDA_VISIBLE_DEVICES": ""}  # fmt: skip
    executable = Path(sys.executable).parent / entry[0]
    command = [str(executable), *entry[1:], *(str(model) if arg == "/model" else arg for arg in default)]
    before = sorted(os.listdir(tmp_path))
    process = subprocess.Popen(command, env=env, cwd=scratch, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        channel = grpc.insecure_channel(f"127.0.0.1:{port}")
        grpc.channel_ready_future(channel).result(timeout=120)
        client = Client(f"127.0.0.1:{port}").start()
        assert len(in_rig(client.step())[0]) == 8
    finally:
        process.terminate()
        output = process.communicate(timeout=30)[0].decode()
    assert f"127.0.0.1:{port}" in output, output
    assert sorted(os.listdir(tmp_path)) == before
    assert sorted(p.name for p in model.iterdir()) == sorted(p.name for p in LEAD_FOLDER.iterdir())
