"""NAVSIM adapter: synthetic OpenScene data -> convert -> read back, checked against the generator's ground truth."""

import json
import math
import pickle
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from lead_s2r.cli import main as cli_main
from lead_s2r.convert import convert
from lead_s2r.geometry import to_local
from lead_s2r.image_headers import jpeg_size
from lead_s2r.schema import BevClassNavsim, BoxClass, Command, MapKind
from lead_s2r.shards import load_manifest, read_samples
from lead_s2r.synthetic import navsim as synth
from lead_s2r.synthetic import navsim_camera as synth_camera
from lead_s2r.synthetic import navsim_map as synth_map
from lead_s2r_adapters.navsim import NavsimAdapter
from lead_s2r_adapters.navsim_io import NavsimFormatError, load_log, quaternion_yaw, read_pcd

SCENES_PER_LOG = synth.FRAMES - synth.HISTORY - synth.FUTURE + 1


@pytest.fixture(scope="module")
def raw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("navsim_raw")
    assert cli_main(["synth", "navsim", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def converted(raw: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("navsim_out")
    adapter = NavsimAdapter(scene_filter=str(raw / "scene_filters" / "navmini.yaml"), maps=str(raw / "maps"))
    result = convert(adapter, raw, out)
    assert result.ok, result.errors
    return out


@pytest.fixture(scope="module")
def samples(converted: Path) -> dict[str, dict]:
    return {s["meta"]["extras"]["navsim"]["scene_token"]: s for s in read_samples(converted)}


def raw_frames(raw: Path) -> dict[str, list[dict]]:
    """Each log's frames, read with plain pickle (the test trusts its own generator's files)."""
    return {p.stem: pickle.loads(p.read_bytes()) for p in sorted((raw / "navsim_logs" / "mini").glob("*.pkl"))}


def spec_of(log_name: str) -> synth.LogSpec:
    return next(spec for spec in synth.log_specs(None) if spec.name == log_name)


def test_every_filtered_token_is_one_sample(raw: Path, converted: Path, samples: dict) -> None:
    tokens = yaml.safe_load((raw / "scene_filters" / "navmini.yaml").read_text())["tokens"]
    assert sorted(samples) == sorted(tokens)
    assert len(tokens) == len(synth.LOGS) * SCENES_PER_LOG
    manifest = load_manifest(converted)
    assert manifest.num_rows == len(tokens)
    assert set(manifest["split"].to_pylist()) == {"navmini"}


def test_ego_round_trip(raw: Path, samples: dict) -> None:
    for log_name, frames in raw_frames(raw).items():
        truth = synth.ego_states(spec_of(log_name))
        for current in range(synth.HISTORY - 1, synth.FRAMES - synth.FUTURE):
            sample = samples[frames[current]["token"]]
            meta = sample["meta"]
            poses = truth["poses"]
            expected = to_local(poses[current - 3 : current + 11], poses[current])
            got = np.concatenate([sample["past"], sample["future"]])
            np.testing.assert_allclose(got[:, 1:], expected, atol=2e-4)
            np.testing.assert_allclose(got[:, 0], np.arange(-1.5, 5.01, 0.5), atol=1e-6)
            vx, vy, ax, ay = truth["dynamics"][current]
            assert meta["ego"]["velocity"] == pytest.approx([vx, vy])
            assert meta["ego"]["acceleration"] == pytest.approx([ax, ay])
            assert meta["ego"]["speed"] == pytest.approx(math.hypot(vx, vy))
            command = {(1, 0, 0, 0): Command.LEFT, (0, 1, 0, 0): Command.STRAIGHT, (0, 0, 0, 1): Command.UNKNOWN}
            assert meta["ego"]["command"] == command[spec_of(log_name).command]
            assert meta["timestamp_us"] == frames[current]["timestamp"]
            assert meta["frame_idx"] == current
            assert meta["location"] == "us-nv-las-vegas-strip"  # 'las_vegas' alias resolved
            assert meta["extras"]["navsim"]["roadblock_ids"] == list(spec_of(log_name).roadblocks)


def test_sensors_round_trip(raw: Path, samples: dict) -> None:
    frames = raw_frames(raw)[synth.LOGS[0].name]
    frame = frames[5]
    sample = samples[frame["token"]]
    blobs = raw / "sensor_blobs" / "mini"
    lidar2ego = np.eye(4)
    lidar2ego[:3, 3] = synth.LIDAR2EGO_TRANSLATION
    for camera in sample["meta"]["cameras"]:
        native = camera["native_name"]
        assert sample[f"cam_{camera['id']}"] == (blobs / frame["cams"][native]["data_path"]).read_bytes()
        calib = synth.camera_calibration(native)
        sensor2lidar = np.eye(4)
        sensor2lidar[:3, :3], sensor2lidar[:3, 3] = calib["sensor2lidar_rotation"], calib["sensor2lidar_translation"]
        np.testing.assert_allclose(camera["cam_to_ego"], lidar2ego @ sensor2lidar, atol=1e-12)
        np.testing.assert_allclose(camera["K"], calib["cam_intrinsic"])
        assert (camera["width"], camera["height"]) == synth.IMAGE_SIZE
    pcd = (blobs / frame["lidar_path"]).read_bytes()
    points = np.frombuffer(pcd[pcd.index(b"DATA binary\n") + 12 :], "<f4").reshape(-1, 6)
    np.testing.assert_allclose(sample["lidar"][:, :3], points[:, :3] + synth.LIDAR2EGO_TRANSLATION, atol=1e-4)
    np.testing.assert_array_equal(sample["lidar"][:, 3:], points[:, 3:])
    assert sample["meta"]["lidar_columns"] == list(synth.PCD_FIELDS)


def test_boxes_and_agent_futures_round_trip(raw: Path, samples: dict) -> None:
    classes = {"vehicle": BoxClass.VEHICLE, "pedestrian": BoxClass.PEDESTRIAN, "bicycle": BoxClass.BICYCLE}
    classes["traffic_cone"] = BoxClass.TRAFFIC_CONE
    for log_name, frames in raw_frames(raw).items():
        spec = spec_of(log_name)
        poses = synth.ego_states(spec)["poses"]
        agents = synth.agents_for(spec, poses[0])
        for current in range(synth.HISTORY - 1, synth.FRAMES - synth.FUTURE):
            sample = samples[frames[current]["token"]]
            tracks = sample["meta"]["extras"]["navsim"]["track_tokens"]
            future = sample["agents_future"]
            assert list(tracks) == list(frames[current]["anns"]["track_tokens"])
            all_tracks = [*frames[0]["anns"]["track_tokens"][:4], frames[8]["anns"]["track_tokens"][-1]]
            for agent, token in zip(agents, all_tracks, strict=True):
                seen_now = agent.first <= current <= agent.last
                assert (token in tracks) == seen_now
                if seen_now:
                    box = sample["boxes"][tracks.index(token)]
                    t = current * 0.5
                    local = to_local(np.r_[agent.centre(t), agent.yaw], poses[current])
                    np.testing.assert_allclose(box[[0, 1, 6]], local, atol=1e-4)
                    np.testing.assert_allclose(box[3:6], agent.size, atol=1e-6)
                    velocity = to_local(np.r_[agent.velocity_at(t), 0.0], np.r_[0.0, 0.0, poses[current, 2]])[:2]
                    np.testing.assert_allclose(box[7:9], velocity, atol=1e-4)
                    assert box[9] == classes[agent.name]
                row = tracks.index(token) if seen_now else _later_row(future, agent)
                for k in range(synth.FUTURE):
                    frame = current + 1 + k
                    assert future["valid"][row, k] == (agent.first <= frame <= agent.last)
                    if future["valid"][row, k]:
                        expected = to_local(np.r_[agent.centre(frame * 0.5), agent.yaw], poses[current])
                        np.testing.assert_allclose(future["poses"][row, k], expected, atol=1e-3)
            np.testing.assert_allclose(future["t"], np.arange(1, synth.FUTURE + 1) * 0.5)
            assert int(future["num_boxes"]) == len(tracks)


def _later_row(future: dict, agent: synth.Agent) -> int:
    """The row of a track absent from the current boxes: past the boxes, matched by class and size."""
    rows = [
        i
        for i in range(int(future["num_boxes"]), len(future["class"]))
        if np.allclose(future["size"][i], agent.size) and future["valid"][i].any()
    ]
    assert len(rows) == 1, (agent, future["size"], future["valid"])
    return rows[0]


def test_left_turn_ends_with_positive_y(raw: Path, samples: dict) -> None:
    frames = raw_frames(raw)[synth.LOGS[1].name]
    last = samples[frames[synth.FRAMES - synth.FUTURE - 1]["token"]]
    x, y, yaw = last["future"][-1, 1:]
    assert y > 10.0 and yaw > 1.4 and x > 0


def test_cam_to_ego_projects_object_on_the_right_into_the_right_half(raw: Path, samples: dict) -> None:
    sample = samples[raw_frames(raw)[synth.LOGS[0].name][3]["token"]]
    camera = next(c for c in sample["meta"]["cameras"] if c["native_name"] == "CAM_F0")
    pedestrian = sample["boxes"][sample["boxes"][:, 9] == BoxClass.PEDESTRIAN][0]
    assert pedestrian[1] < 0  # on the right
    corner = np.r_[pedestrian[0] - pedestrian[3] / 2, pedestrian[1] - pedestrian[4] / 2, pedestrian[2], 1.0]
    in_camera = np.linalg.inv(camera["cam_to_ego"]) @ corner
    u, v, w = np.asarray(camera["K"]) @ in_camera[:3]
    assert w > 0 and camera["width"] / 2 < u / w < camera["width"] and 0 < v / w < camera["height"]


def test_front_camera_shows_the_lead_car_where_its_calibration_projects_it(raw: Path, samples: dict) -> None:
    sample = samples[raw_frames(raw)[synth.LOGS[0].name][3]["token"]]
    camera = next(c for c in sample["meta"]["cameras"] if c["native_name"] == "CAM_F0")
    image = cv2.imdecode(np.frombuffer(sample["cam_front"], np.uint8), cv2.IMREAD_COLOR).astype(int)
    lead = sample["boxes"][0]  # the car the ego follows, in its lane
    assert lead[9] == BoxClass.VEHICLE and abs(lead[1]) < 0.1 and 10.0 < lead[0] < 40.0
    rear_centre = np.r_[lead[0] - lead[3] / 2, lead[1], lead[2], 1.0]  # the face the camera sees
    u, v, w = np.asarray(camera["K"]) @ (np.linalg.inv(camera["cam_to_ego"]) @ rear_centre)[:3]
    colour = image[int(v / w), int(u / w)]
    assert np.abs(colour - synth_camera.BOX_COLOURS["vehicle"]).max() < 30, colour
    road = synth_camera.AREAS[-1][1]
    assert np.abs(image[-1, camera["width"] // 2 + 10] - road).max() < 30  # the lane just ahead: road
    assert np.abs(image[0].mean(axis=0) - synth_camera.SKY).max() < 30


def _polygons(scoring: dict, kinds: set[int]) -> list[np.ndarray]:
    xy, offsets = scoring["polygon_xy"], scoring["polygon_offsets"]
    return [xy[offsets[i] : offsets[i + 1]] for i, kind in enumerate(scoring["polygon_kind"]) if kind in kinds]


def _inside(point: np.ndarray, ring: np.ndarray) -> bool:
    return cv2.pointPolygonTest(ring.astype(np.float32).reshape(-1, 1, 2), tuple(map(float, point)), False) >= 0


def test_ego_starts_inside_drivable_polygons(samples: dict) -> None:
    drivable = {MapKind.ROADBLOCK, MapKind.INTERSECTION, MapKind.CARPARK_AREA}
    for sample in samples.values():
        rings = _polygons(sample["scoring"], drivable)
        assert any(_inside(np.zeros(2), ring) for ring in rings)
        assert not any(_inside(np.array([0.0, 40.0]), ring) for ring in rings)  # 40 m to the left: off-road


def test_red_light_polygon_only_while_red(samples: dict) -> None:
    left_turn = synth_map.TRAFFIC_LIGHT_CONNECTORS[1]
    for sample in samples.values():
        scoring = sample["scoring"]
        np.testing.assert_allclose(scoring["red_light_t"], np.arange(synth.FUTURE + 1) * 0.5)
        assert left_turn in scoring["polygon_id"][scoring["polygon_kind"] == MapKind.LANE_CONNECTOR]
        offsets = scoring["red_light_offsets"]
        for k in range(len(offsets) - 1):
            red = set(scoring["red_light_ids"][offsets[k] : offsets[k + 1]].tolist())
            frame = sample["meta"]["frame_idx"] + k
            assert (left_turn in red) == (frame < synth.GREEN_FRAME)


def test_lane_connectivity_and_attributes_round_trip(samples: dict) -> None:
    scoring = next(iter(samples.values()))["scoring"]
    expected = {(lc.fid, lc.from_lane, lc.to_lane) for lc in synth_map.LANE_CONNECTORS}
    assert set(map(tuple, scoring["lane_connector_edges"].tolist())) == expected
    expected_rb = {(fid, *ends) for fid, ends in synth_map.ROADBLOCK_CONNECTORS.items()}
    assert set(map(tuple, scoring["roadblock_connector_edges"].tolist())) == expected_rb
    for lane in synth_map.LANES + synth_map.LANE_CONNECTORS:
        i = list(scoring["polygon_id"]).index(lane.fid)
        assert scoring["polygon_parent"][i] == lane.parent
        assert scoring["polygon_speed_limit"][i] == pytest.approx(lane.speed_limit)
        j = list(scoring["centerline_id"]).index(lane.fid)
        line = scoring["centerline_xy"][scoring["centerline_offsets"][j] : scoring["centerline_offsets"][j + 1]]
        assert len(line) == len(lane.centerline)
    assert scoring["origin"].dtype == np.float64 and scoring["polygon_xy"].dtype == np.float32


def test_bev_semantic_labels_road_and_vehicles(samples: dict) -> None:
    sample = next(iter(samples.values()))
    bev, bev_meta = sample["bev_semantic"], sample["meta"]["bev"]
    assert bev.shape == (256, 256) and bev_meta["classes"] == "navsim"
    assert bev[128, 128] in (BevClassNavsim.ROAD, BevClassNavsim.CENTERLINE)
    assert bev[128, 10] == BevClassNavsim.BACKGROUND  # 29.5 m to the left: no road
    lead = sample["boxes"][sample["boxes"][:, 9] == BoxClass.VEHICLE][0]
    row, col = int((32 - lead[0]) / 0.25), int((32 - lead[1]) / 0.25)
    assert bev[row, col] == BevClassNavsim.VEHICLES


def test_without_maps_no_scoring(raw: Path) -> None:
    adapter = NavsimAdapter(split="mini")
    log = adapter.list_logs(raw)[0]
    sample = next(adapter.iter_samples(log))
    assert "scoring" not in sample and "bev_semantic" not in sample
    assert sample["meta"]["split"] == "mini" and sample["meta"]["has"]["lidar"]


def test_broken_inputs_are_isolated(raw: Path, tmp_path: Path) -> None:
    src = tmp_path / "src"
    shutil.copytree(raw, src)
    names = [spec.name for spec in synth.LOGS]
    frames = raw_frames(raw)
    missing_blob = src / "sensor_blobs" / "mini" / frames[names[0]][8]["cams"]["CAM_B0"]["data_path"]
    missing_blob.unlink()
    evil = pickle.dumps([{"token": shutil.rmtree}])  # any non-numpy global must be refused
    (src / "navsim_logs" / "mini" / f"{names[1]}.pkl").write_bytes(evil)
    filter_path = src / "scene_filters" / "navmini.yaml"
    config = yaml.safe_load(filter_path.read_text())
    config["tokens"].append("deadbeefdeadbeef")
    filter_path.write_text(yaml.safe_dump(config))
    result = convert(NavsimAdapter(scene_filter=str(filter_path)), src, tmp_path / "out")
    records = [json.loads(line) for line in (tmp_path / "out" / "errors.jsonl").read_text().splitlines()]
    errors = {e["log"]: e["error"] for e in records if "log" in e}
    assert str(missing_blob) in errors[names[0]]
    assert "refers to shutil.rmtree" in errors[names[1]] and names[1] in errors[names[1]]
    (bad,) = [e for e in records if "scene_filter" in e]  # reported when the filter is checked, as logs are listed
    assert bad["scene_filter"] == str(filter_path) and "deadbeefdeadbeef" in bad["error"]
    assert f"field 'tokens' has {SCENES_PER_LOG + 1} tokens" in bad["error"]
    assert f"unreadable logs: {names[1]}" in bad["error"]
    assert result.samples == SCENES_PER_LOG
    assert {s["meta"]["log_id"] for s in read_samples(tmp_path / "out")} == {names[2]}


def test_unknown_box_velocities_stay_unknown(raw: Path, tmp_path: Path, samples: dict) -> None:
    """OpenScene's NaN velocity is unknown, never 0 m/s: NaN in x or y makes the box's vx, vy NaN (and its future
    velocities); a NaN z alone changes nothing; an infinite one is one error naming the field."""
    src = tmp_path / "src"
    shutil.copytree(raw, src)
    name = synth.LOGS[0].name
    log_path = src / "navsim_logs" / "mini" / f"{name}.pkl"
    frames = pickle.loads(log_path.read_bytes())
    unknown_track = frames[0]["anns"]["track_tokens"][0]
    for frame in frames:
        anns = frame["anns"]
        velocity = np.array(anns["gt_velocity_3d"], np.float64)
        velocity[np.asarray(anns["track_tokens"]) == unknown_track, 1] = np.nan
        velocity[np.asarray(anns["track_tokens"]) != unknown_track, 2] = np.nan
        anns["gt_velocity_3d"] = velocity
    log_path.write_bytes(pickle.dumps(frames))
    adapter = NavsimAdapter(scene_filter=str(src / "scene_filters" / "navmini.yaml"), maps=str(src / "maps"))
    assert convert(adapter, src, tmp_path / "out").ok
    checked = 0
    for sample in read_samples(tmp_path / "out"):
        if sample["meta"]["log_id"] != name:
            continue
        token = sample["meta"]["extras"]["navsim"]["scene_token"]
        current = next(frame for frame in frames if frame["token"] == token)
        is_unknown = np.asarray(current["anns"]["track_tokens"]) == unknown_track
        velocity, before = sample["boxes"][:, 7:9], samples[token]["boxes"][:, 7:9]
        assert np.isnan(velocity[is_unknown]).all() and np.isfinite(before[is_unknown]).all()
        np.testing.assert_array_equal(velocity[~is_unknown], before[~is_unknown])
        future = sample["agents_future"]
        assert np.isnan(
            future["velocity"][: len(is_unknown)][is_unknown][future["valid"][: len(is_unknown)][is_unknown]]
        ).all()
        checked += int(is_unknown.any())
    assert checked > 0
    frames[3]["anns"]["gt_velocity_3d"] = np.full_like(frames[3]["anns"]["gt_velocity_3d"], np.inf)
    log_path.write_bytes(pickle.dumps(frames))
    result = convert(adapter, src, tmp_path / "again")
    (error,) = [json.loads(line) for line in (tmp_path / "again" / "errors.jsonl").read_text().splitlines()]
    assert error["log"] == name and "field 'gt_velocity_3d' holds infinite values" in error["error"]
    assert result.samples == len(samples) - SCENES_PER_LOG


def test_a_scene_filter_cut_at_a_line_names_the_logs_it_drops(raw: Path, tmp_path: Path) -> None:
    """Fuzzing found it: navmini.yaml cut short still parses, and the scenes of the last log it reaches vanished."""
    src = tmp_path / "src"
    shutil.copytree(raw, src)
    filter_path = src / "scene_filters" / "navmini.yaml"
    lines = filter_path.read_text().splitlines(keepends=True)
    first_token = lines.index("tokens:\n") + 1
    kept = first_token + SCENES_PER_LOG + 1  # the first log's scenes and one of the second's
    filter_path.write_text("".join(lines[:kept]).rstrip("\n"))  # cut inside the list, at the end of a token
    result = convert(NavsimAdapter(scene_filter=str(filter_path)), src, tmp_path / "out")
    records = [json.loads(line) for line in (tmp_path / "out" / "errors.jsonl").read_text().splitlines()]
    unselected, last = [e["error"] for e in records if "scene_filter" in e]
    names = [spec.name for spec in synth.LOGS]
    assert f"field 'log_names' names {len(names) - 2} logs none of whose scenes field 'tokens' selects" in unselected
    assert names[2] in unselected and names[1] not in unselected
    assert f"field 'tokens' ends with 1 of the {SCENES_PER_LOG} scenes of log {names[1]}" in last
    assert "lists 100% of a typical other log's (cut short?)" in last and not result.ok
    assert result.samples == SCENES_PER_LOG + 1


def test_bad_pickle_and_token_list(tmp_path: Path, raw: Path) -> None:
    (tmp_path / "garbage.pkl").write_bytes(b"not a pickle")
    with pytest.raises(NavsimFormatError, match=r"garbage\.pkl"):
        load_log(tmp_path / "garbage.pkl")
    (tmp_path / "empty.pkl").write_bytes(pickle.dumps({"a": 1}))
    with pytest.raises(NavsimFormatError, match="list of frame dicts"):
        load_log(tmp_path / "empty.pkl")
    token = raw_frames(raw)[synth.LOGS[2].name][4]["token"]
    (tmp_path / "tokens.txt").write_text(f"# one scene\n{token}\n")
    adapter = NavsimAdapter(scene_filter=str(tmp_path / "tokens.txt"))
    got = [s for log in adapter.list_logs(raw) for s in adapter.iter_samples(log)]
    assert [s["meta"]["extras"]["navsim"]["scene_token"] for s in got] == [token]


def test_filter_without_frame_interval_cuts_back_to_back_scenes(tmp_path: Path, raw: Path) -> None:
    """NAVSIM's SceneFilter turns a missing / null frame_interval into num_frames: windows do not overlap."""
    log_name = synth.LOGS[0].name
    config = {"num_history_frames": 4, "num_future_frames": 4, "frame_interval": None, "log_names": [log_name]}
    (tmp_path / "backtoback.yaml").write_text(yaml.safe_dump(config))
    adapter = NavsimAdapter(scene_filter=str(tmp_path / "backtoback.yaml"))
    got = [s["meta"]["frame_idx"] for log in adapter.list_logs(raw) for s in adapter.iter_samples(log)]
    assert got == [3, 11]  # windows [0, 8) and [8, 16) of 20 frames; [16, 24) is too short


def test_pcd_reader_mixed_types_and_ascii(tmp_path: Path) -> None:
    header = "VERSION 0.7\nFIELDS x y ring\nSIZE 4 8 1\nTYPE F F U\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\n"
    records = np.array([(1.5, -2.25, 7), (3.0, 4.0, 255)], dtype=[("x", "<f4"), ("y", "<f8"), ("r", "u1")])
    (tmp_path / "b.pcd").write_bytes((header + "DATA binary\n").encode() + records.tobytes())
    (tmp_path / "a.pcd").write_text(header + "DATA ascii\n1.5 -2.25 7\n3 4 255\n")
    for name in ("a.pcd", "b.pcd"):
        points, columns = read_pcd(tmp_path / name)
        assert columns == ["x", "y", "ring"]
        np.testing.assert_array_equal(points, [[1.5, -2.25, 7], [3, 4, 255]])
    (tmp_path / "short.pcd").write_bytes((header + "DATA binary\n").encode() + records.tobytes()[:5])
    with pytest.raises(NavsimFormatError, match=r"short\.pcd"):
        read_pcd(tmp_path / "short.pcd")


@settings(max_examples=25, deadline=None)
@given(st.integers(8, 300), st.integers(8, 300), st.floats(-math.pi + 1e-6, math.pi - 1e-6))
def test_jpeg_size_and_yaw_properties(width: int, height: int, yaw: float) -> None:
    ok, data = cv2.imencode(".jpg", np.zeros((height, width, 3), np.uint8))
    assert ok and jpeg_size(data.tobytes()) == (width, height)
    assert quaternion_yaw(synth.yaw_quaternion(yaw)) == pytest.approx(yaw, abs=1e-9)


def test_splits_deal_one_sequence_of_logs_into_split_folders(tmp_path: Path) -> None:
    synth.generate(tmp_path, seed=0, splits={"trainval": 2, "test": 2})
    specs = synth.log_specs(4)
    folders = {
        split: sorted(p.stem for p in (tmp_path / "navsim_logs" / split).glob("*.pkl"))
        for split in ("trainval", "test")
    }
    assert folders == {"trainval": sorted(s.name for s in specs[:2]), "test": sorted(s.name for s in specs[2:])}
    assert all(
        (tmp_path / "sensor_blobs" / split / name).is_dir() for split, names in folders.items() for name in names
    )
    assert not (tmp_path / "navsim_logs" / synth.DATA_SPLIT).exists()
    assert len(yaml.safe_load((tmp_path / "scene_filters" / "navmini.yaml").read_text())["log_names"]) == 4


def test_logs_past_the_first_three_are_drawn_from_their_ranges_and_stay_on_the_route() -> None:
    specs = synth.log_specs(30, seed=1)
    assert specs[:3] == list(synth.LOGS) and len({s.name for s in specs}) == 30
    t_end = (synth.FRAMES - 1) * synth.DT_US / 1e6
    for i, spec in enumerate(specs[3:], start=3):
        ranges, base = synth.RANGES[i % 3], synth.LOGS[i % 3]
        assert spec.lanes == base.lanes and spec.command == base.command
        assert ranges.speed[0] <= spec.speed <= ranges.speed[1] and ranges.accel[0] <= spec.accel <= ranges.accel[1]
    speeds = [s.speed for s in specs[3::3]]
    assert min(speeds) < 7.0 and max(speeds) > 9.5  # spans the cruise range, not copies
    assert synth.log_specs(30, seed=1) == specs and synth.log_specs(30, seed=2)[3:] != specs[3:]
    for spec in specs:
        assert spec.start + spec.speed * t_end + 0.5 * spec.accel * t_end**2 < synth.route_line(spec.lanes).length
        assert spec.speed + spec.accel * t_end <= 13.4  # the roads' speed limit
        if synth.LEFT_TURN in spec.lanes:  # the front bumper reaches the left-turn connector once it is green
            entry = (synth_map.JUNCTION_X - synth.EGO_FRONT - spec.start) / spec.speed
            assert synth.GREEN_FRAME * synth.DT_US / 1e6 < entry < 7.5 and spec.speed <= 6.5
