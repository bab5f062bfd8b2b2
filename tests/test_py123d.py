"""The py123d adapter against logs and maps written by py123d's own writers (``lead_s2r.synthetic.py123d``):
every field against the values written, the frame conversion, error isolation, resume and inspection."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

pytest.importorskip("py123d", reason="py123d is installed with --no-deps in CI (docs/datasets/py123d.md)")

from lead_s2r.convert import convert
from lead_s2r.geometry import rotate, to_local, wrap_angle
from lead_s2r.report.inspection import inspect_dataset
from lead_s2r.schema import BevClassNavsim, BoxClass, MapKind
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import carla_lead as lead
from lead_s2r.synthetic import py123d as synth
from lead_s2r_adapters.py123d import Py123dAdapter

FRAMES = 8  # route-folder frames of the drive; the 123D log holds its whole 10 Hz drive


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, list[dict]]]:
    src = tmp_path_factory.mktemp("py123d_src")
    synth.write_log(src, "log-left", index=0, frames=FRAMES)
    synth.write_log(src, "log-right", index=1, frames=FRAMES, codec="laz")
    out = src.parent / "py123d_out"
    result = convert(Py123dAdapter(), src, out)
    assert not result.errors
    logs: dict[str, list[dict]] = {}
    for sample in read_samples(out):
        logs.setdefault(sample["meta"]["log_id"], []).append(sample)
    return src, logs


def _drive(index: int) -> tuple[lead.Drive, list[lead.Actor]]:
    """The drive and the actors write_log wrote for it."""
    drive, actors = lead.drive_and_actors(index, FRAMES, np.random.default_rng(0))
    return drive, synth.log_actors(actors)


def test_ego_past_and_future_are_rear_axle_poses_in_the_t0_frame(converted) -> None:
    _, logs = converted
    drive, _ = _drive(0)
    world = synth.iso(drive.pose[:: synth.STEP])  # write_log's rear-axle poses at 10 Hz
    samples = logs["nuplan_test/log-left"]
    assert [s["meta"]["frame_idx"] for s in samples] == list(range(len(world) - 40))  # 4 s future at 10 Hz
    for sample in samples:
        i = sample["meta"]["frame_idx"]
        future = sample["future"]
        np.testing.assert_allclose(future[:, 0], np.arange(1, 41) / 10, atol=1e-6)
        want = to_local(world[i + 1 : i + 41], world[i])
        np.testing.assert_allclose(future[:, 1:3], want[:, :2], atol=1e-4)
        np.testing.assert_allclose(future[:, 3], wrap_angle(want[:, 2]), atol=1e-5)
        past = sample["past"]
        assert past[-1].tolist() == [0.0, 0.0, 0.0, 0.0] and len(past) == min(i, 20) + 1
        np.testing.assert_allclose(past[:, 1:3], to_local(world[max(i - 20, 0) : i + 1], world[i])[:, :2], atol=1e-4)
        ego = sample["meta"]["ego"]
        step = i * synth.STEP
        assert ego["speed"] == pytest.approx(drive.speed[step])
        assert ego["yaw_rate"] == pytest.approx(-drive.yaw_rate[step])  # CARLA's clockwise rate, ISO sign
        assert sample["meta"]["timestamp_us"] == 1_000_000 + step * 50_000


def test_a_left_turn_ends_left_and_a_right_turn_right(converted) -> None:
    _, logs = converted
    left, right = logs["nuplan_test/log-left"][0], logs["nuplan_test/log-right"][0]
    assert left["future"][-1, 2] > 5 and left["future"][-1, 3] > 1.0
    assert right["future"][-1, 2] < -5 and right["future"][-1, 3] < -1.0


def test_vehicle_and_camera_calibration_move_from_the_imu_to_the_rear_axle(converted) -> None:
    _, logs = converted
    meta = logs["nuplan_test/log-left"][0]["meta"]
    assert meta["vehicle"]["rear_axle_to_center"] == pytest.approx(1.1 + 0.4)  # centre 1.1 m ahead of the IMU
    (camera,) = meta["cameras"]
    assert camera["id"] == "front" and camera["native_name"] == "CAM_F0"
    assert camera["K"] == [[40.0, 0.0, 32.0], [0.0, 40.0, 24.0], [0.0, 0.0, 1.0]]
    cam_to_ego = np.asarray(camera["cam_to_ego"])
    np.testing.assert_allclose(cam_to_ego[:3, 3], [1.5 + 0.4, 0.0, 1.4 + 0.3])
    np.testing.assert_allclose(cam_to_ego[:3, :3] @ [0, 0, 1], [1, 0, 0], atol=1e-12)  # optical axis forward
    np.testing.assert_allclose(cam_to_ego[:3, :3] @ [1, 0, 0], [0, -1, 0], atol=1e-12)  # image x to the right


def test_jpegs_are_the_bytes_written(converted) -> None:
    _, logs = converted
    for sample in logs["nuplan_test/log-left"]:
        assert sample["cam_front"] == synth.jpeg(sample["meta"]["frame_idx"])


def test_lidar_points_and_features_in_the_rear_axle_frame(converted) -> None:
    _, logs = converted
    for log in ("nuplan_test/log-left", "nuplan_test/log-right"):  # IPC and LAZ payloads
        for sample in logs[log][:3]:
            assert sample["meta"]["lidar_columns"] == ["x", "y", "z", "intensity"]
            want = synth.lidar_points(sample["meta"]["frame_idx"]) - np.array(synth.REAR_AXLE_TO_IMU)
            np.testing.assert_allclose(sample["lidar"][:, :3], want, atol=5e-3)  # py123d's LAZ scale: 1 cm
            np.testing.assert_array_equal(sample["lidar"][:, 3], np.arange(24))


def test_boxes_classes_velocities_and_agent_futures(converted) -> None:
    _, logs = converted
    drive, actors = _drive(0)
    movers = [a for a in actors if a.cls != "traffic_light"]
    for sample in logs["nuplan_test/log-left"][::5]:
        i = sample["meta"]["frame_idx"]
        ego = synth.iso(drive.pose[i * synth.STEP])
        boxes = sample["boxes"]
        assert sample["meta"]["extras"]["py123d"]["box_tokens"] == [str(a.actor_id) for a in movers]
        want_class = {"car": BoxClass.VEHICLE, "walker": BoxClass.PEDESTRIAN, "static": BoxClass.TRAFFIC_CONE}
        assert boxes[:, 9].tolist() == [want_class[a.cls] for a in movers]
        for row, actor in zip(boxes, movers, strict=True):
            world = synth.iso(actor.pose_at(np.array([i * synth.STEP]))[0])
            local = to_local(world[None], ego)[0]
            np.testing.assert_allclose(row[[0, 1]], local[:2], atol=1e-4)
            assert row[6] == pytest.approx(wrap_angle(local[2]), abs=1e-5)
            assert row[2] == pytest.approx(actor.extent[2], abs=1e-5)
            np.testing.assert_allclose(row[3:6], 2 * np.asarray(actor.extent), atol=1e-5)
            velocity = rotate(actor.speed * np.array([np.cos(world[2]), np.sin(world[2])]), -ego[2])
            np.testing.assert_allclose(row[7:9], velocity, atol=1e-4)
        future = sample["agents_future"]
        assert int(future["num_boxes"]) == len(movers) and future["valid"].all()
        later = synth.iso(movers[0].pose_at(np.array([(i + 10) * synth.STEP]))[0])
        np.testing.assert_allclose(future["poses"][0, 9, :2], to_local(later[None], ego)[0, :2], atol=1e-4)


def test_traffic_lights_and_route_kept(converted) -> None:
    _, logs = converted
    first = logs["nuplan_test/log-left"][0]
    assert first["meta"]["extras"]["py123d"]["traffic_lights"] == [[synth.LANES["turn"][0], "RED"]]
    route = first["route"]
    assert np.abs(route[0]).max() < 0.5 and len(route) <= 50  # py123d's driven path from the ego on, 50 m at most
    steps = np.hypot(*np.diff(route, axis=0).T)
    np.testing.assert_allclose(steps[:-1], 1.0, atol=0.01)  # a point a metre, the last one at the path's end
    assert not first["meta"]["has"]["target_points"]  # only LEAD's logs get target points


def test_map_gives_the_scoring_context_and_bev(converted) -> None:
    _, logs = converted
    sample = logs["nuplan_test/log-left"][0]
    scoring = sample["scoring"]
    kinds = dict(zip(scoring["polygon_id"].tolist(), scoring["polygon_kind"].tolist(), strict=True))
    approach, turn, exit_ = (synth.LANES[n] for n in ("approach", "turn", "exit"))
    assert kinds[approach[0]] == MapKind.LANE and kinds[approach[1]] == MapKind.ROADBLOCK
    assert kinds[turn[0]] == MapKind.LANE_CONNECTOR and kinds[turn[1]] == MapKind.ROADBLOCK_CONNECTOR
    assert kinds[synth.INTERSECTION_ID] == MapKind.INTERSECTION
    assert scoring["route_roadblock_ids"].tolist() == [approach[1], turn[1], exit_[1]]
    assert scoring["lane_connector_edges"].tolist() == [[turn[0], approach[0], exit_[0]]]
    assert scoring["roadblock_connector_edges"].tolist() == [[turn[1], approach[1], exit_[1]]]
    assert scoring["red_light_ids"][0] == turn[0]  # red at t0 on the connector's lane id
    assert sample["meta"]["bev"]["classes"] == "navsim"
    assert sample["bev_semantic"][128, 128] == BevClassNavsim.CENTERLINE  # the ego stands on its lane's centreline
    assert (sample["bev_semantic"] == BevClassNavsim.ROAD).sum() > 500


def test_pdms_of_the_logged_future(converted) -> None:
    from lead_s2r.predictions import Prediction
    from lead_s2r.scoring.navsim.pdms_scorer import PDMSScorer

    _, logs = converted
    sample = logs["nuplan_test/log-left"][4]
    ego_past = sample["scoring"]["ego_past"]  # t, x, y, yaw, vx, vy, ax, ay: EPDMS's history comfort reads it
    assert ego_past.shape == (5, 8) and ego_past[-1, :4].tolist() == [0.0, 0.0, 0.0, 0.0]
    np.testing.assert_allclose(ego_past[:, 4:6], [[6.0, 0.0]] * 5, atol=1e-9)
    future = sample["future"]
    prediction = Prediction(sample["__key__"], sample["meta"]["dataset"], future[:, 0], future[:, 1:3], future[:, 3])
    row = PDMSScorer().score_sample(sample, [prediction])
    assert row["valid"] and row["no_at_fault_collisions"] == 1.0 and row["drivable_area_compliance"] == 1.0
    assert row["driving_direction_compliance"] == 1.0 and row["progress_m"] > 20  # the 4 s turn on the map's lanes
    assert 0.9 < row["score"] <= 1.0


def test_list_valued_sync_columns_of_older_py123d_read_alike(converted, tmp_path: Path) -> None:
    """Before 0.7, sync.arrow held a list of row indices per modality and iteration; the first one is used."""
    src, logs = converted
    folder = tmp_path / "logs" / "nuplan_test" / "log-left"
    folder.parent.mkdir(parents=True)
    shutil.copytree(src / "logs" / "nuplan_test" / "log-left", folder)
    table = pa.ipc.open_file(pa.memory_map(str(folder / "sync.arrow"))).read_all()
    columns = {}
    for name in table.column_names:
        values = table[name].to_pylist()
        columns[name] = values if name.startswith("sync.") else [[] if v is None else [v, v + 1] for v in values]
    fields = [f if f.name.startswith("sync.") else pa.field(f.name, pa.list_(pa.int64())) for f in table.schema]
    listed = pa.table(columns, schema=pa.schema(fields, metadata=table.schema.metadata))
    with pa.OSFile(str(folder / "sync.arrow"), "wb") as sink, pa.ipc.new_file(sink, listed.schema) as writer:
        writer.write_table(listed)
    convert(Py123dAdapter(maps=str(src / "maps")), tmp_path, tmp_path / "out")
    again = list(read_samples(tmp_path / "out"))
    assert [s["__key__"] for s in again] == [s["__key__"] for s in logs["nuplan_test/log-left"]]
    for new, old in zip(again, logs["nuplan_test/log-left"], strict=True):
        np.testing.assert_array_equal(new["future"], old["future"])
        np.testing.assert_array_equal(new["boxes"], old["boxes"])
        assert new["cam_front"] == old["cam_front"] and "scoring" in new


def test_a_log_without_ego_dynamics_takes_the_speed_from_its_poses(tmp_path: Path) -> None:
    synth.write_log(tmp_path / "src", "log-poses", index=0, frames=FRAMES, dynamics=False)
    convert(Py123dAdapter(), tmp_path / "src", tmp_path / "out")
    samples = list(read_samples(tmp_path / "out"))
    assert samples
    for sample in samples:
        ego = sample["meta"]["ego"]
        assert ego["speed"] == pytest.approx(6.0, abs=0.05) and ego["acceleration"] == [0.0, 0.0]
        assert "finite differences" in sample["meta"]["extras"]["py123d"]["ego_dynamics"]
        assert "ego_past" not in sample["scoring"]  # EPDMS's history comfort needs logged dynamics


@pytest.mark.parametrize("damaged", ["box_detections_se3.arrow", "sync.arrow", "camera.pcam_f0.arrow"])
def test_a_truncated_file_fails_its_log_only(tmp_path: Path, damaged: str) -> None:
    good = synth.write_log(tmp_path / "src", "log-good", index=2, frames=FRAMES)
    bad = synth.write_log(tmp_path / "src", "log-bad", index=0, frames=FRAMES)
    blob = (bad / damaged).read_bytes()
    (bad / damaged).write_bytes(blob[: len(blob) // 2])
    result = convert(Py123dAdapter(), tmp_path / "src", tmp_path / "out")
    assert result.logs_converted == 1 and len(result.errors) == 1
    (line,) = (tmp_path / "out" / "errors.jsonl").read_text().splitlines()
    error = json.loads(line)
    assert str(bad / damaged) in error["error"] and "not a readable Arrow IPC file" in error["error"]
    assert {s["meta"]["log_id"] for s in read_samples(tmp_path / "out")} == {f"nuplan_test/{good.name}"}


def test_resume_skips_finished_logs_and_inspect_passes(converted, tmp_path: Path) -> None:
    src, _ = converted
    out = tmp_path / "out"
    first = convert(Py123dAdapter(stride=5), src, out)
    again = convert(Py123dAdapter(stride=5), src, out)
    assert first.logs_converted == 2 and again.logs_resumed == 2 and again.samples == 0
    assert [s["meta"]["frame_idx"] for s in read_samples(out) if s["meta"]["log_id"].endswith("left")] == [0, 5]
    report = inspect_dataset(out)
    assert report["samples"] == first.samples == 4 and report["invalid"] == []
    assert report["by_dataset_split"] == {"py123d_nuplan/nuplan_test": 4}


def test_cli_synth_lists_and_converts(tmp_path: Path) -> None:
    cli = [sys.executable, "-m", "lead_s2r.cli"]
    subprocess.run([*cli, "synth", "py123d", "--out", str(tmp_path / "src"), "--logs", "1"], check=True)
    listed = subprocess.run([*cli, "adapters"], capture_output=True, text=True, check=True).stdout
    assert "py123d" in listed
    run = subprocess.run(
        [*cli, "convert", "py123d", "--src", str(tmp_path / "src"), "--out", str(tmp_path / "out"), "--stride", "4"],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr
    iterations = len(lead.drive_and_actors(0, 16, np.random.default_rng(0))[0].pose[:: synth.STEP])
    per_log = len(range(0, iterations - 40, 4))  # every 4th frame with a whole 4 s future
    datasets = [s["meta"]["dataset"] for s in read_samples(tmp_path / "out")]
    assert sorted(set(datasets)) == ["lead123d", "py123d_nuplan"] and len(datasets) == 2 * per_log


def test_without_msgpack_the_error_names_the_extra(converted, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    src, _ = converted
    monkeypatch.setitem(sys.modules, "msgpack", None)  # as if the py123d extra were not installed
    result = convert(Py123dAdapter(), src, tmp_path / "out")
    assert result.logs_converted == 0 and len(result.errors) == 2
    assert all("pip install 'lead-s2r[py123d]'" in json.dumps(error) for error in result.errors)


def test_lead_s2r_score_computes_pdms_on_a_converted_123d_log(converted, tmp_path: Path) -> None:
    """PDMS is defined on any sample with a map's ``scoring`` context, so a 123D log scores like a NAVSIM one."""
    from lead_s2r.scoring.run import planner_predictions, score_predictions

    src, _ = converted
    data = src.parent / "py123d_out"
    predictions = planner_predictions("human", data, tmp_path / "predictions.parquet")
    report = score_predictions("pdms@navsim-1.1", predictions, [data], tmp_path / "scores")
    aggregates = report["aggregates"]
    assert aggregates["frames"] > 0 and aggregates["frames_skipped_other_dataset"] == 0
    assert 0.9 < aggregates["pdms"] <= 1.0 and aggregates["no_at_fault_collisions"] == 1.0


def test_a_null_box_velocity_is_unknown_not_zero_and_scores_as_standing(converted, tmp_path: Path) -> None:
    """py123d writes a box velocity null where its source has none: NaN in vx, vy (and the box's agents_future
    velocity), the rest of the box as with velocities; PDMS treats the box as standing (docs/metrics.md)."""
    from lead_s2r.predictions import Prediction
    from lead_s2r.schema import validate
    from lead_s2r.scoring.navsim.pdms_scorer import PDMSScorer
    from lead_s2r.scoring.pdm.sample import agent_tracks

    synth.write_log(tmp_path / "src", "log-left", index=0, frames=FRAMES, box_velocities=False)
    result = convert(Py123dAdapter(), tmp_path / "src", tmp_path / "out")
    assert result.ok and result.samples == len(converted[1]["nuplan_test/log-left"])
    samples = list(read_samples(tmp_path / "out"))
    for sample, known in zip(samples, converted[1]["nuplan_test/log-left"], strict=True):
        validate(sample)
        boxes, future = sample["boxes"], sample["agents_future"]
        assert np.isnan(boxes[:, 7:9]).all() and np.isfinite(boxes[:, :7]).all()
        np.testing.assert_array_equal(np.delete(boxes, [7, 8], axis=1), np.delete(known["boxes"], [7, 8], axis=1))
        assert np.isnan(future["velocity"][future["valid"]]).all()
        np.testing.assert_array_equal(future["poses"], known["agents_future"]["poses"])
    sample = samples[4]  # test_pdms_of_the_logged_future's, with velocities
    tracks = agent_tracks(sample)
    assert np.isfinite(tracks["agent_velocity"]).all() and (tracks["agent_velocity"][tracks["agent_valid"]] == 0).all()
    future = sample["future"]
    prediction = Prediction(sample["__key__"], sample["meta"]["dataset"], future[:, 0], future[:, 1:3], future[:, 3])
    row = PDMSScorer().score_sample(sample, [prediction])
    assert row["valid"] and np.isfinite(row["score"]) and row["no_at_fault_collisions"] == 1.0


def test_a_box_velocity_of_nan_in_one_axis_is_refused(tmp_path: Path) -> None:
    """Only a wholly unknown velocity is NaN; a partly NaN one is damage, named with its file and row."""
    log = synth.write_log(tmp_path / "src", "log-left", index=0, frames=FRAMES)
    path, name = log / "box_detections_se3.arrow", "box_detections_se3.velocity_3d"
    table = pa.ipc.open_file(pa.memory_map(str(path))).read_all()
    rows = table[name].to_pylist()
    rows[0][0] = [1.0, float("nan"), 0.0]
    table = table.set_column(table.column_names.index(name), name, pa.array(rows, table[name].type))
    path.unlink()
    with pa.OSFile(str(path), "wb") as sink, pa.ipc.new_file(sink, table.schema) as writer:
        writer.write_table(table)
    result = convert(Py123dAdapter(), tmp_path / "src", tmp_path / "out")
    assert result.samples == 0 and len(result.errors) == 1
    error = json.dumps(result.errors)
    assert str(path) in error and "row 0: a box value is not finite" in error
