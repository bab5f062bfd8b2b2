"""The leaderboard agent end to end on a synthetic CARLA route: a tiny model trained here by `lead-s2r fit`, driven
through leaderboard-shaped sensor data; its preprocessing held against the adapter + training transform."""

import copy
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from closed_loop_scene import global_plan, sensor_data
from tiny_models import TINY, sensor_spec

from lead_s2r.closed_loop import agent as agent_module
from lead_s2r.closed_loop.agent import AgentConfigError, ClosedLoopConfig, LeadS2RAgent, parse_bool
from lead_s2r.closed_loop.check import straight_route, synthetic_input
from lead_s2r.closed_loop.checkpoint import UnsupportedCheckpoint, check_drivable, rig_for, saved_config
from lead_s2r.closed_loop.sensors import Rig, SensorInputError, sensor_specs
from lead_s2r.convert import convert
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.models import lead
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_driver import LeadDriver
from lead_s2r.registry import LogRef
from lead_s2r.schema import validate
from lead_s2r.synthetic import carla_lead as synth
from lead_s2r.training.cli import run_lightning_cli
from lead_s2r.training.weights import find_checkpoint
from lead_s2r_adapters.carla_lead import CarlaLeadAdapter

#: Tests that drive need the leaderboard's types; lead-s2r[carla] installs the client wherever PyPI has a wheel.
CARLA_CLIENT = {"modname": "carla", "reason": "the CARLA client (pip install 'lead-s2r[carla]') builds CARLA's types"}
pytestmark = pytest.mark.usefixtures("one_thread")

LEAD_DRIVER = "lead_s2r.models.lead_driver.LeadDriver"
MODEL = {**TINY, "use_planning_decoder": True}  # TFv6 on 32 x 96 (3:1, LEAD's 3-camera rig)
#: LTFv6 for NAVSIM with CARLA heads, so it reads the CARLA batches of the scene (and no target point).
LTF = {**TINY, "use_navsim_data": True, "use_carla_data": True, "LTF": True, "use_planning_decoder": True}


def fit_config(root: Path, data: Path, model: dict, steps: int, class_path: str = LEAD_DRIVER) -> Path:
    """A smoke-recipe-like LightningCLI config: CARLA only, CARLA supervising planning too."""
    config = {
        "seed_everything": 0,
        "trainer": {
            "accelerator": "cpu", "max_epochs": 1, "limit_train_batches": steps, "logger": False,
            "enable_progress_bar": False, "enable_model_summary": False, "default_root_dir": str(root),
            "callbacks": [{"class_path": "lightning.pytorch.callbacks.ModelCheckpoint",
                           "init_args": {"dirpath": str(root / "checkpoints"), "save_last": True}}],
        },
        "model": {
            "model": {"class_path": class_path, "init_args": {"config": json.loads(json.dumps(model))}},
            "supervise": {"carla": ["planning", "perception"]},
        },
        "data": {
            "train": {"carla": {"paths": [str(data)], "cameras": ["carla_mosaic"]}},
            "schedule": {"anchors": {0: {"carla": 2}}, "global_batch_size": 2},
            "steps_per_epoch": steps,
            "shuffle_buffer": 4,
        },
    }  # fmt: skip
    root.mkdir(parents=True, exist_ok=True)
    path = root / "fit.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A synthetic left-turn route, converted, and a tiny LEAD TFv6 fitted on it for 2 steps (its run folder)."""
    pytest.importorskip(**CARLA_CLIENT)
    root = tmp_path_factory.mktemp("closed_loop")
    synth.generate(root / "src", count=1, frames=4)
    convert(CarlaLeadAdapter(), root / "src", root / "data", shard_size=8)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the shared CPU; restored for the other test modules
    try:
        run_lightning_cli(["fit", "--config", str(fit_config(root / "run", root / "data", MODEL, steps=2))])
    finally:
        torch.set_num_threads(threads)
    folder = next((root / "src" / "data").glob("*/*"))
    return {"run": root / "run", "folder": folder, "root": root}


def make_agent(checkpoint: str | Path, folder: Path) -> LeadS2RAgent:
    """The leaderboard's order: construct, set_global_plan, setup."""
    agent = LeadS2RAgent("localhost", 2000, False)
    agent.set_global_plan(*global_plan(folder))
    agent.setup(str(checkpoint))
    return agent


def test_the_agent_drives_50_steps_with_controls_in_range(scene):
    carla = pytest.importorskip(**CARLA_CLIENT)
    agent = make_agent(scene["run"], scene["folder"])
    assert LeadS2RAgent.get_ros_version() == 0 and agent_module.get_entry_point() == "LeadS2RAgent"
    assert agent.rig == Rig("CARLA_LEADERBOARD2_3CAMERAS", lidar=True, radar=True)
    ids = {spec["id"] for spec in agent.sensors()}
    assert ids == {"rgb_1", "rgb_2", "rgb_3", "lidar_0", "lidar_1", "radar_1", "radar_2", "radar_3", "radar_4",
                   "imu", "gps", "speed"}  # fmt: skip
    frames = [sensor_data(scene["folder"], f) for f in range(4)]
    controls = [agent.run_step(frames[step * 4 // 50], step * 0.05) for step in range(50)]
    assert all(isinstance(c, carla.VehicleControl) for c in controls)
    first = controls[0]
    assert (first.throttle, first.brake, first.steer) == (0.0, 1.0, 0.0)
    for control in controls:
        assert -1.0 <= control.steer <= 1.0 and 0.0 <= control.throttle <= 1.0 and 0.0 <= control.brake <= 1.0
        assert not (control.throttle > 0 and control.brake > 0)
    agent.destroy()


def test_preprocessing_equals_the_adapter_and_training_transform(scene):
    agent = make_agent(scene["run"], scene["folder"])
    batch = agent.preprocess(sensor_data(scene["folder"], 0), 0.0)
    validate(agent.last_sample)  # a valid schema sample, like the adapter's
    folder = scene["folder"]
    log = LogRef(f"{folder.parent.name}/{folder.name}", "train", str(folder), {})
    recorded = next(CarlaLeadAdapter(tp_distance=3.25).iter_samples(log))
    want = SourceTransform("carla", input_spec(agent.model.config), cameras=["carla_mosaic"])(recorded)
    got = {k: v[0] for k, v in batch.items() if isinstance(v, torch.Tensor)}
    image_error = (got["rgb"].float() - want["rgb"].float()).abs()
    assert image_error.mean() < 2.0 and image_error.max() < 40  # one extra JPEG round trip at quality 90
    torch.testing.assert_close(got["lidar_bev"], want["lidar_bev"])
    assert want["lidar_bev"].sum() > 0
    torch.testing.assert_close(got["target_points"], want["target_points"], atol=0.02, rtol=0)
    assert bool(got["target_points_valid"].all() and want["target_points_valid"].all())
    torch.testing.assert_close(got["speed"], want["speed"])
    torch.testing.assert_close(got["acceleration"], want["acceleration"])
    assert int(got["command"]) == int(want["command"])
    torch.testing.assert_close(got["radar"], want["radar"], atol=1e-3, rtol=0)
    torch.testing.assert_close(got["radar_valid"], want["radar_valid"])


def drive(agent: LeadS2RAgent, folder: Path, steps: int) -> list:
    """Controls of ``steps`` ticks on the scene's recorded frames, each checked to be in range."""
    controls = [agent.run_step(sensor_data(folder, step % 4), step * 0.05) for step in range(steps)]
    for control in controls:
        assert -1.0 <= control.steer <= 1.0 and 0.0 <= control.throttle <= 1.0 and 0.0 <= control.brake <= 1.0
    return controls


def test_a_lead_checkpoint_folder_and_its_ensemble_drive(scene, tmp_path):
    from lead_reference import TINY_CARLA

    folder = tmp_path / "lead"
    lead.export_checkpoint(lead.model_from_config(TINY_CARLA), folder)
    agent = make_agent(folder, scene["folder"])
    assert isinstance(agent.model, LeadDriver) and not agent.model.training
    assert agent.rig == Rig("CARLA_LEADERBOARD2_3CAMERAS", lidar=True, radar=True)
    assert agent.classes == pytest.approx((0.0, 4.0, 8.0, 10.0, 13.88888888, 16.0, 17.77777777, 20.0))
    batch = agent.preprocess(sensor_data(scene["folder"], 1), 0.05)
    assert batch["rgb"].shape[-2:] == (384, 1152) and batch["lidar_bev"].shape[-2:] == (192, 160)
    assert set(agent.predict(batch)) >= {"waypoints", "route", "target_speed_logits"}
    drive(agent, scene["folder"], 3)
    shutil.copy(folder / "model_0000.pth", folder / "model_0001.pth")
    assert isinstance(make_agent(folder, scene["folder"]).model.network, lead.LeadEnsemble)
    with pytest.raises(UnsupportedCheckpoint, match="plans for no source 'navsim'"):
        check_drivable(agent.model, "navsim", folder)


def test_a_run_trained_with_leads_architecture_drives(scene):
    from lead_reference import TINY_CARLA

    root = scene["root"] / "lead_run"
    config = fit_config(root, scene["root"] / "data", TINY_CARLA, steps=1)
    run_lightning_cli(["fit", "--config", str(config)])
    agent = make_agent(root, scene["folder"])
    assert isinstance(agent.model, LeadDriver) and agent.spec.radar and agent.spec.lidar_raster
    assert drive(agent, scene["folder"], 3)[0].brake == 1.0


def test_an_ltfv6_navsim_checkpoint_is_refused(scene):
    root = scene["root"] / "ltf"
    run_lightning_cli(["fit", "--config", str(fit_config(root, scene["root"] / "data", LTF, steps=1))])
    with pytest.raises(UnsupportedCheckpoint, match="reads no route target points"):
        make_agent(root, scene["folder"])


def test_a_copied_checkpoint_drives_alone(scene, tmp_path):
    path = tmp_path / "copied.ckpt"  # the weights without the run folder's config.yaml
    shutil.copy(scene["run"] / "checkpoints" / "last.ckpt", path)
    copied, in_run = make_agent(path, scene["folder"]), make_agent(scene["run"], scene["folder"])
    assert copied.model.config == in_run.model.config
    for key, value in in_run.model.state_dict().items():
        torch.testing.assert_close(copied.model.state_dict()[key], value, rtol=0, atol=0)


def test_an_older_checkpoint_needs_its_run_config(scene, tmp_path):
    saved = torch.load(scene["run"] / "checkpoints" / "last.ckpt", weights_only=True)
    del saved["hyper_parameters"]["model"]  # as written before checkpoints described their network
    torch.save(saved, tmp_path / "old.ckpt")
    with pytest.raises(UnsupportedCheckpoint, match=r"describe no network .* config\.yaml"):
        make_agent(tmp_path / "old.ckpt", scene["folder"])
    shutil.copy(scene["run"] / "config.yaml", tmp_path / "config.yaml")  # now it sits in its run folder
    assert make_agent(tmp_path / "old.ckpt", scene["folder"]).model.config.camera_tile == (32, 32)


def test_rig_follows_the_model_image():
    assert rig_for(input_spec(LeadConfig(use_planning_decoder=True))) == "CARLA_LEADERBOARD2_3CAMERAS"
    six = LeadConfig(use_planning_decoder=True, carla_root="data/carla_leaderboad2_v10")
    assert rig_for(input_spec(six)) == "CARLA_LEADERBOARD2_6CAMERAS"
    assert rig_for(sensor_spec(image_size=(384, 1024))) == "CARLA_PY123D_1CAMERA"
    assert (
        rig_for(input_spec(LeadConfig(use_navsim_data=True, LTF=True, use_planning_decoder=True))) == "NAVSIM_4CAMERAS"
    )
    specs = sensor_specs(Rig("CARLA_LEADERBOARD2_6CAMERAS", lidar=False, radar=False))
    assert [s["yaw"] for s in specs if s["type"] == "sensor.camera.rgb"] == [-57.5, 0.0, 57.5, -122.5, 180.0, 122.5]


def test_the_benchmark_flag_is_a_real_boolean(tmp_path):
    assert ClosedLoopConfig.from_agent_config("run", {"IS_BENCH2DRIVE": "0"}).bench2drive is False
    config = ClosedLoopConfig.from_agent_config("run+route_42", {"IS_BENCH2DRIVE": "True"})
    assert config.bench2drive is True and config.checkpoint == "run"
    assert ClosedLoopConfig.from_agent_config("run+x", {}).checkpoint == "run+x"
    assert parse_bool("X", "off") is False
    with pytest.raises(ValueError, match="IS_BENCH2DRIVE"):
        ClosedLoopConfig.from_agent_config("run", {"IS_BENCH2DRIVE": "maybe"})
    path = tmp_path / "drive.yaml"
    path.write_text("checkpoint: runs/a\ncreeping: true\ncontroller: waypoint\n")
    config = ClosedLoopConfig.from_agent_config(str(path), {})
    assert (config.checkpoint, config.creeping, config.controller) == ("runs/a", True, "waypoint")
    config.rig, config.device = "CARLA_LEADERBOARD2_3CAMERAS", "cpu"
    assert ClosedLoopConfig.read(config.write(tmp_path / "written.yaml")) == config  # every field round-trips


def test_the_heuristics_and_the_waypoint_controller_switch_on_by_config(scene, tmp_path):
    options = {"controller": "waypoint", "creeping": True, "stop_sign_slowdown": True}
    path = ClosedLoopConfig(str(scene["run"]), **options).write(tmp_path / "drive.yaml")
    agent = make_agent(path, scene["folder"])
    frame = sensor_data(scene["folder"], 1)
    controls = [agent.run_step(frame, step * 0.05) for step in range(5)]
    assert controls[0].brake == 1.0
    for control in controls:
        assert -1.0 <= control.steer <= 1.0 and 0.0 <= control.throttle <= 1.0 and 0.0 <= control.brake <= 1.0
    assert agent.creeper.stuck_frames == 0  # moving at the recorded speed: never stuck


def test_the_saved_config_is_found_beside_a_logger_run(tmp_path):
    (tmp_path / "checkpoints").mkdir()
    checkpoint = tmp_path / "checkpoints" / "last.ckpt"
    checkpoint.touch()
    for version in (0, 1):
        (tmp_path / "lightning_logs" / f"version_{version}").mkdir(parents=True)
        config = tmp_path / "lightning_logs" / f"version_{version}" / "config.yaml"
        config.write_text(f"v: {version}\n")
        os.utime(config, (1000 + version, 1000 + version))  # version 1 is the newer run
    assert find_checkpoint(tmp_path) == checkpoint
    assert saved_config(checkpoint) == tmp_path / "lightning_logs" / "version_1" / "config.yaml"
    (tmp_path / "config.yaml").write_text("v: run\n")
    assert saved_config(checkpoint) == tmp_path / "config.yaml"


def test_closed_loop_check_drives_a_carla_run_offline_and_refuses_a_navsim_model(scene, capsys):
    from lead_s2r.cli import main

    assert main(["closed-loop", "check", str(scene["run"]), "--ticks", "3"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"closed-loop check passed: {scene['run']}"
    assert lines[1].startswith("  rig CARLA_LEADERBOARD2_3CAMERAS, 12 sensors: rgb_1, rgb_2, rgb_3, lidar_0")
    assert lines[2].startswith("  3 ticks on synthetic sensor data: steer ")
    ltf = scene["root"] / "ltf_check"
    run_lightning_cli(["fit", "--config", str(fit_config(ltf, scene["root"] / "data", LTF, steps=1))])
    assert main(["closed-loop", "check", str(ltf)]) == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "reads no route target points" in error and error.startswith("error: ")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"checkpoint: runs/a\ncreeping: 7\n", "creeping is 7, not bool"),  # drove as True
        (b"checkpoint: runs/a\njpeg_quality: true\n", "jpeg_quality is True, not int"),  # encoded at quality 1
        (b"checkpoint: runs/a\ndevice: 7\n", "device is 7, not str or null"),  # was a torch error at setup
        (b"checkpoint: runs/a\ncontroller: x\n", "controller is 'x', not one of 'route', 'waypoint'"),
        (b"checkpoint: runs/a\nrig: NOPE\n", "rig 'NOPE' is not a LEAD camera rig"),
        (b"- checkpoint\n", r"unknown keys \['checkpoint'\] or no 'checkpoint'"),  # was a TypeError
        (b"checkpoint: \xff\n", "cannot read the agent config"),  # was a UnicodeDecodeError
    ],
)
def test_a_damaged_agent_config_is_named(tmp_path, content, message):
    path = tmp_path / "drive.yaml"
    path.write_bytes(content)
    with pytest.raises(AgentConfigError, match=r"drive\.yaml: " + message):
        ClosedLoopConfig.from_agent_config(str(path), {})


def test_damaged_sensor_data_is_named_dropped_or_braked_on(scene):
    """docs/closed_loop.md's table of damaged sensor data, one row each."""
    agent = LeadS2RAgent("localhost", 2000, False)
    agent.set_global_plan(*straight_route())
    agent.setup(str(scene["run"]))
    ticks = [synthetic_input(agent.sensors(), frame, np.random.default_rng(frame)) for frame in range(3)]
    agent.run_step(ticks[0], 0.0)

    def control(twin: LeadS2RAgent, tick: dict) -> tuple[float, float, float]:
        got = twin.run_step(tick, 0.05)
        return got.steer, got.throttle, got.brake

    with pytest.raises(SensorInputError, match=r"^sensor 'lidar_0': missing from the tick's input_data"):
        copy.deepcopy(agent).run_step({k: v for k, v in ticks[1].items() if k != "lidar_0"}, 0.05)
    with pytest.raises(SensorInputError, match=r"sensor 'imu': expected 7 numbers, got shape \(6,\)"):
        copy.deepcopy(agent).run_step({**ticks[1], "imu": (1, ticks[1]["imu"][1][:6])}, 0.05)
    with pytest.raises(SensorInputError, match=r"sensor 'rgb_1': expected a BGRA uint8 384x384x4 image"):
        copy.deepcopy(agent).run_step({**ticks[1], "rgb_1": (1, ticks[1]["rgb_1"][1].astype(np.float32))}, 0.05)
    pristine = control(copy.deepcopy(agent), ticks[1])
    nan_rows = np.vstack([ticks[1]["radar_1"][1], [[math.nan, 0, 0, 0], [1e30, 0, 0, 0]]]).astype(np.float32)
    assert control(copy.deepcopy(agent), {**ticks[1], "radar_1": (1, nan_rows)}) == pristine  # rows dropped
    braking = copy.deepcopy(agent)
    assert control(braking, {**ticks[1], "gps": (1, np.array([math.nan, 0.0, 0.0]))}) == (0.0, 0.0, 1.0)
    assert control(braking, ticks[2]) == control(copy.deepcopy(agent), ticks[2])  # the route state as it was
