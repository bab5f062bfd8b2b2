"""LEAD's own 123D recordings: one drive written as a LEAD route folder and as LEAD's 123D log converts to the
same samples; each of the three departures from py123d's conventions is corrected; LEAD's route planner; labels."""

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

pytest.importorskip("py123d", reason="py123d is installed with --no-deps in CI (docs/datasets/py123d.md)")

from lead_s2r.convert import convert
from lead_s2r.geometry import carla_points_to_iso
from lead_s2r.schema import BoxClass
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import carla_lead as lead
from lead_s2r.synthetic import py123d as synth
from lead_s2r_adapters import py123d_labels, py123d_lead
from lead_s2r_adapters.carla_lead import CarlaLeadAdapter
from lead_s2r_adapters.navsim_io import quaternion_yaw
from lead_s2r_adapters.py123d import Py123dAdapter
from lead_s2r_adapters.py123d_frames import pose_matrix

FRAMES = 8
#: the route folder's 3 s future at 20 Hz is compared with the 123D log's at 10 Hz
FUTURE_S = lead.EGO_FUTURE_STEPS * lead.DT


def _by_frame(out: Path) -> dict[int, dict]:
    return {s["meta"]["frame_idx"]: s for s in read_samples(out)}


@pytest.fixture(scope="module", params=[0, 1], ids=["left", "right"])
def twins(request, tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict[int, dict], dict[int, dict], Path]:
    index = request.param
    root = tmp_path_factory.mktemp(f"twin{index}")
    lead.write_route(root / "folders", index, FRAMES, np.random.default_rng(0))
    synth.write_lead_log(root / "py123d", index, FRAMES, 0)
    assert not convert(CarlaLeadAdapter(), root / "folders", root / "out_folders").errors
    assert not convert(Py123dAdapter(future_s=FUTURE_S, plan_spacing=10.0), root / "py123d", root / "out_py123d").errors
    return index, _by_frame(root / "out_folders"), _by_frame(root / "out_py123d"), root


def _pairs(folders: dict[int, dict], logs: dict[int, dict]) -> list[tuple[dict, dict]]:
    """Route-folder frame k (20 Hz tick 5k) and the 123D iteration of the same tick (every second tick)."""
    ticks = {k: k * lead.SAVE_FREQ for k in folders}
    pairs = [(folders[k], logs[t // synth.STEP]) for k, t in ticks.items() if t % synth.STEP == 0]
    assert len(pairs) >= 3
    return pairs


def test_the_same_drive_converts_to_the_same_ego_future_boxes_and_target_points(twins) -> None:
    index, folders, logs, _ = twins
    drive, _ = lead.drive_and_actors(index, FRAMES, np.random.default_rng(0))
    compared = 0
    for folder, log in _pairs(folders, logs):
        assert log["meta"]["dataset"] == "lead123d" and log["meta"]["is_synthetic"]
        for name in ("speed", "yaw_rate"):
            assert log["meta"]["ego"][name] == pytest.approx(folder["meta"]["ego"][name], abs=1e-6)
        for name in ("velocity", "acceleration"):
            np.testing.assert_allclose(log["meta"]["ego"][name], folder["meta"]["ego"][name], atol=1e-6)
        assert log["meta"]["ego"]["command"] == folder["meta"]["ego"]["command"]
        np.testing.assert_allclose(log["future"], folder["future"][1::2], atol=1e-4)  # 20 Hz -> 10 Hz
        ids = folder["meta"]["extras"]["carla_lead"]["box_ids"]
        rows = {str(i): row for i, row in zip(ids, folder["boxes"], strict=True)}
        tokens = log["meta"]["extras"]["py123d"]["box_tokens"]
        assert set(tokens) == {
            str(i) for i, c in zip(ids, folder["boxes"][:, 9], strict=True) if c != BoxClass.TRAFFIC_LIGHT
        }
        for token, row in zip(tokens, log["boxes"], strict=True):
            np.testing.assert_allclose(row[:9], rows[token][:9], atol=1e-4)
            # LEAD's exporter labels emergency vehicles VEHICLE; the route folders keep their blueprint
            assert row[9] == rows[token][9] or (row[9], rows[token][9]) == (
                BoxClass.VEHICLE,
                BoxClass.EMERGENCY_VEHICLE,
            )
        # the previous target point always, the current one until the turn (the route folders' synthetic plan
        # also holds a mid-turn point, which a plan rebuilt from the driven path cannot know)
        np.testing.assert_allclose(log["target_points"][0], folder["target_points"][0], atol=0.01)
        if drive.arc[folder["meta"]["frame_idx"] * lead.SAVE_FREQ] < lead.TURN_START - 3.25:  # turn start not popped
            np.testing.assert_allclose(log["target_points"][1], folder["target_points"][1], atol=0.01)
            compared += 1
    assert compared >= 1


def test_departure_1_world_velocity_and_degrees_become_body_frame_si(twins) -> None:
    index, _, logs, root = twins
    folder = next((root / "py123d" / "logs").glob("*/*"))
    table = pa.ipc.open_file(pa.memory_map(str(folder / "ego_state_se3.arrow"))).read_all()
    stored = np.asarray(table["ego_state_se3.dynamic_state_se3"].to_pylist())
    poses = np.asarray(table["ego_state_se3.imu_se3"].to_pylist())
    turning = int(np.argmax(np.abs(stored[:, 8])))
    assert abs(stored[turning, 8]) > 30  # deg/s as CARLA reports it
    sample = logs[turning]
    heading = quaternion_yaw(poses[turning, 3:])
    assert np.hypot(*stored[turning, :2]) == pytest.approx(sample["meta"]["ego"]["speed"])
    assert abs(np.sin(heading)) > 0.1 and abs(stored[turning, 1]) > 0.5  # stored in the world frame
    np.testing.assert_allclose(sample["meta"]["ego"]["velocity"], [sample["meta"]["ego"]["speed"], 0.0], atol=1e-9)
    assert sample["meta"]["ego"]["yaw_rate"] == pytest.approx(-np.deg2rad(stored[turning, 8]))
    assert np.sign(sample["meta"]["ego"]["yaw_rate"]) == (1 if index == 0 else -1)  # a left turn turns left
    raw = convert(Py123dAdapter(lead="no", future_s=FUTURE_S), root / "py123d", root / "raw")
    assert raw.samples == len(logs)
    assert _by_frame(root / "raw")[turning]["meta"]["ego"]["yaw_rate"] == pytest.approx(stored[turning, 8])


def test_departure_2_traffic_lights_stay_carla_lane_indices(twins) -> None:
    _, _, logs, _ = twins
    extras = logs[0]["meta"]["extras"]["py123d"]
    assert extras["lead"]["traffic_lights"] == {"carla_lane_index": [-1], "status": [2]}
    assert "traffic_lights" not in extras  # never read as map lane ids


def test_departure_3_lidar_in_leads_own_frame(twins) -> None:
    index, _, logs, _ = twins
    drive, actors = lead.drive_and_actors(index, FRAMES, np.random.default_rng(0))
    for i in (0, 5):
        native = synth.lead_lidar(actors, drive.pose[i * synth.STEP], i * synth.STEP)
        want = carla_points_to_iso(native)  # what the carla_lead adapter makes of LEAD's route-folder LiDAR
        np.testing.assert_allclose(logs[i]["lidar"][:, :3], want, atol=5e-3)  # LAZ keeps centimetres


def test_lead_logs_are_recognised_by_their_metadata() -> None:
    lincoln = {"vehicle_name": "carla_lincoln_mkz_2020"}
    assert py123d_lead.is_lead_log({"dataset": "carla", "split": "carla_train"}, lincoln)
    assert py123d_lead.is_lead_log({"dataset": "lead123d", "split": "train"}, lincoln)
    assert not py123d_lead.is_lead_log({"dataset": "nuplan", "split": "nuplan_test"}, lincoln)
    assert not py123d_lead.is_lead_log({"dataset": "carla", "split": "carla_train"}, {"vehicle_name": "other"})
    with pytest.raises(ValueError, match="lead must be one of"):
        Py123dAdapter(lead="maybe")


def test_road_options_and_sparse_plan_of_a_left_turn() -> None:
    drive = lead.make_drive("left", 200, np.random.default_rng(0))
    route = synth.iso(drive.path[::10])[:, :2]  # a point a metre
    options = py123d_lead.road_options(route)
    turn = np.flatnonzero(options == py123d_lead.LEFT)
    assert turn[0] == lead.TURN_START and turn[-1] == 23  # the 10 m quarter turn spans arc 8 to 23.7
    assert set(options[: turn[0]]) == set(options[turn[-1] + 1 :]) == {py123d_lead.LANEFOLLOW}
    points, plan = py123d_lead.sparse_plan(route, options, spacing=10.0)
    # the turn's start (8), a point once more than 10 m were walked (20: the leaderboard counts the steps after
    # the kept point, and the turn's chords are a little under 1 m), the turn's end (24), then one every 11 m
    np.testing.assert_allclose(points[:6], route[[0, 8, 20, 24, 35, 46]])
    assert plan[:6].tolist() == [4, 1, 1, 4, 4, 4]
    right = synth.iso(lead.make_drive("right", 200, np.random.default_rng(0)).path[::10])[:, :2]
    assert set(py123d_lead.road_options(right)) == {py123d_lead.RIGHT, py123d_lead.LANEFOLLOW}


def test_label_tables_agree_with_py123d() -> None:
    from py123d.datatypes.detections.box_detection_label import DefaultBoxDetectionLabel
    from py123d.parser.registry import NuPlanBoxDetectionLabel

    for enum in (DefaultBoxDetectionLabel, NuPlanBoxDetectionLabel):
        table = py123d_labels.KNOWN_ENUMS[enum.__name__]
        assert table == {int(v): v.to_default().name for v in enum}
    qualified = "py123d.parser.registry.WODPerceptionBoxDetectionLabel"  # resolved through py123d itself
    from py123d.parser.registry import WODPerceptionBoxDetectionLabel

    for label in WODPerceptionBoxDetectionLabel:
        cls, raw = py123d_labels.box_class(qualified, int(label))
        default = label.to_default().name
        if default in py123d_labels.DEFAULT_TO_BOXCLASS:
            assert (cls, raw) == (py123d_labels.DEFAULT_TO_BOXCLASS[default], None)
        else:
            assert (cls, raw) == (BoxClass.GENERIC_OBJECT, f"WODPerceptionBoxDetectionLabel.{default}")
    assert py123d_labels.box_class("nowhere.UnknownLabel", 3) == (BoxClass.GENERIC_OBJECT, "UnknownLabel#3")
    assert py123d_labels.box_class("x.DefaultBoxDetectionLabel", 11) == (
        BoxClass.GENERIC_OBJECT,
        "DefaultBoxDetectionLabel.OTHER",
    )
    assert py123d_labels.box_class("x.DefaultBoxDetectionLabel", 0) == (None, None)  # the ego's own box


def test_quaternion_yaw_and_pose_matrix() -> None:
    quarter = np.array([1.0, 2.0, 3.0, np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])
    assert quaternion_yaw(quarter[3:]) == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(pose_matrix(quarter) @ [1, 0, 0, 1], [1.0, 3.0, 3.0, 1.0], atol=1e-12)
    flipped = np.array([0, 0, 0, 0.0, 0.0, 0.0, 1.0])  # 180 degrees about z
    assert abs(quaternion_yaw(flipped[3:])) == pytest.approx(np.pi)
