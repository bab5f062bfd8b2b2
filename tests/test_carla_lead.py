"""LEAD CARLA adapter: generator -> convert -> read_samples, checked value by value against the raw files.

Expected values are computed here from the raw files with the frame-change formulas written out explicitly
(y and yaw negated, origin moved from the vehicle centre to the rear axle), not through the adapter's helpers.
"""

import json
import lzma
import math
import pickle
import shutil
import warnings
from collections import OrderedDict
from pathlib import Path

import cv2
import laspy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lead_s2r.convert import convert
from lead_s2r.models.input_spec import input_spec
from lead_s2r.schema import BoxClass, Command
from lead_s2r.shards import load_info, load_manifest, read_samples
from lead_s2r.synthetic import carla_lead as synth
from lead_s2r.synthetic import carla_lead_sensors
from lead_s2r_adapters.carla_lead import CarlaLeadAdapter, camera_calibration, hdmap_pixel_to_ego
from lead_s2r_adapters.carla_lead_io import LeadFormatError, array, read_pickle

REAR = 1.389
FRAMES = 12


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, list[dict]]:
    src = tmp_path_factory.mktemp("lead")
    synth.generate(src, count=3, seed=1, frames=FRAMES)
    out = tmp_path_factory.mktemp("out")
    result = convert(CarlaLeadAdapter(rig="both"), src, out)
    assert result.ok, result.errors
    return src, out, list(read_samples(out))


def raw(route: Path, folder: str, name: str) -> object:
    with lzma.open(route / folder / f"{name}.pkl") as file:
        return pickle.load(file)


def route_folder(src: Path, sample: dict) -> Path:
    return src / "data" / sample["meta"]["log_id"]


def expected_poses(xy: np.ndarray, yaw: np.ndarray, view: tuple[float, float, float]) -> np.ndarray:
    """CARLA centre-frame poses -> the (possibly perturbated) view frame -> ISO rear-axle poses."""
    dx, dy = xy[:, 0] - view[0], xy[:, 1] - view[1]
    c, s = math.cos(view[2]), math.sin(view[2])
    x, y, heading = c * dx + s * dy, -s * dx + c * dy, yaw - view[2]
    iso_yaw = -heading
    out = np.column_stack([x - REAR * np.cos(iso_yaw) + REAR, -y - REAR * np.sin(iso_yaw), iso_yaw])
    out[:, 2] = (out[:, 2] + np.pi) % (2 * np.pi) - np.pi
    return out


def expected_points(xy: np.ndarray, view: tuple[float, float, float]) -> np.ndarray:
    """CARLA centre-frame points -> view frame -> ISO rear-axle points (y negated, x shifted by the axle offset)."""
    dx, dy = xy[:, 0] - view[0], xy[:, 1] - view[1]
    c, s = math.cos(view[2]), math.sin(view[2])
    return np.column_stack([c * dx + s * dy + REAR, -(-s * dx + c * dy)])


def expected_box_poses(xy: np.ndarray, yaw: np.ndarray, view: tuple[float, float, float]) -> np.ndarray:
    """Another actor's box centre: moved like a point (no rear-axle shift of its own), heading negated."""
    return np.column_stack([expected_points(xy, view), -(yaw - view[2])])


def assert_poses(actual: np.ndarray, want: np.ndarray, atol: float) -> None:
    """Compare [x, y, yaw] rows, yaw modulo 2 pi (float32 rounding may put -pi at +pi)."""
    np.testing.assert_allclose(actual[..., :2], want[..., :2], atol=atol)
    yaw_error = (np.asarray(actual[..., 2], np.float64) - want[..., 2] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(yaw_error, 0.0, atol=atol)


def view_of(sample: dict, meta: dict) -> tuple[float, float, float]:
    if sample["meta"]["extras"]["carla_lead"]["rig"] == "normal":
        return (0.0, 0.0, 0.0)
    return (0.0, meta["perturbation_translation"], math.radians(meta["perturbation_rotation"]))


def test_round_trip_every_value(converted: tuple[Path, Path, list[dict]]) -> None:
    src, _, samples = converted
    assert len(samples) == 3 * FRAMES * 2
    for sample in samples:
        route, name = route_folder(src, sample), f"{sample['meta']['frame_idx']:04d}"
        meta, boxes = raw(route, "metas", name), raw(route, "bboxes", name)
        view = view_of(sample, meta)
        suffix = "" if view == (0.0, 0.0, 0.0) else "_perturbated"

        fp, fy = np.asarray(meta["future_positions"]), np.asarray(meta["future_yaws"])
        np.testing.assert_allclose(sample["future"][:, 0], np.arange(1, len(fp)) / 20, atol=1e-6)
        assert_poses(sample["future"][:, 1:], expected_poses(fp[1:, :2], fy[1:], view), atol=1e-4)
        pp, py = np.asarray(meta["past_positions"])[::-1], np.asarray(meta["past_yaws"])[::-1]
        assert sample["past"][-1, 0] == 0 and len(sample["past"]) == len(pp)
        assert_poses(sample["past"][:, 1:], expected_poses(pp[:, :2], py, view), atol=1e-4)

        world = np.asarray(meta["next_target_points_3.25"])[:, :2] - meta["pos_global"][:2]
        c, s = math.cos(meta["theta"]), math.sin(meta["theta"])
        local = np.column_stack([c * world[:, 0] + s * world[:, 1], -s * world[:, 0] + c * world[:, 1]])
        want = np.full((3, 2), np.nan)
        want[: min(3, len(local))] = expected_points(local[:3], view)
        np.testing.assert_allclose(sample["target_points"], want, atol=1e-3)

        ego = sample["meta"]["ego"]
        assert ego["speed"] == pytest.approx(meta["speed"])
        assert ego["command_raw"] == meta["next_commands_3.25"][0]
        assert ego["yaw_rate"] == pytest.approx(-meta["angular_velocity_z"])
        np.testing.assert_allclose(
            sample["route"], expected_points(np.asarray(meta["route"], np.float64), view), atol=1e-4
        )

        others = [box for box in boxes if box["class"] != "ego_car"]
        assert sample["meta"]["extras"]["carla_lead"]["box_ids"] == [box["id"] for box in others]
        for row, box in zip(sample["boxes"], others, strict=True):
            pose = expected_box_poses(np.array([box["position"][:2]]), np.array([box["yaw"]]), view)[0]
            assert_poses(row[[0, 1, 6]], pose, atol=1e-4)
            np.testing.assert_allclose(row[2:6], [box["position"][2], *(2 * np.asarray(box["extent"]))], atol=1e-5)
            assert math.hypot(row[7], row[8]) == pytest.approx(box["speed"], rel=1e-5)
        moving = [i for i, box in enumerate(others) if "future_positions" in box]
        agents = sample["agents_future"]
        assert agents["valid"].sum(axis=1).tolist() == [40 if i in moving else 0 for i in range(len(others))]
        for i in moving:
            fut = np.asarray(others[i]["future_positions"], np.float64)
            want = expected_box_poses(fut[1:], np.asarray(others[i]["future_yaws"], np.float64)[1:], view)
            assert_poses(agents["poses"][i], want, atol=1e-3)

        assert sample["cam_carla_mosaic"] == (route / f"rgb{suffix}" / f"{name}.jpg").read_bytes()
        for field, folder in (("semantic_carla_mosaic", "semantics"), ("depth_carla_mosaic", "depth")):
            stored = cv2.imread(str(route / f"{folder}{suffix}" / f"{name}.png"), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(sample[field], stored)
        hdmap = cv2.imread(str(route / f"hdmap{suffix}" / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(sample["bev_semantic"], np.rot90(hdmap))

        las = laspy.read(str(route / "lidar" / f"{name}.laz"))
        xyz = np.column_stack([las.x, las.y, las.z])
        np.testing.assert_allclose(sample["lidar"][:, :2], expected_points(xyz[:, :2], view), atol=1e-3)
        np.testing.assert_allclose(sample["lidar"][:, 2], xyz[:, 2], atol=1e-4)
        np.testing.assert_allclose(sample["lidar"][:, 3], -np.asarray(las["time"], np.float64) / 20, atol=1e-6)

        with np.load(route / f"radar{suffix}" / f"{name}.npz") as npz:
            clouds = [npz[f"radar{i}"].astype(np.float64) for i in range(1, 5)]
        radar = np.concatenate([np.column_stack([c, np.full(len(c), i)]) for i, c in enumerate(clouds)])
        want_radar = np.column_stack([radar[:, 0] + REAR, -radar[:, 1], radar[:, 2:]])
        np.testing.assert_allclose(sample["radar"], want_radar, atol=1e-4)


def test_lidar_points_on_a_box_lie_inside_its_converted_box(converted: tuple[Path, Path, list[dict]]) -> None:
    """The generator scatters LiDAR points inside every box; LiDAR and boxes must land in the same place."""
    src, _, samples = converted
    for sample in samples:
        route, name = route_folder(src, sample), f"{sample['meta']['frame_idx']:04d}"
        raw_boxes = [box for box in raw(route, "bboxes", name) if box["class"] != "ego_car"]
        raw_lidar = laspy.read(str(route / "lidar" / f"{name}.laz"))
        raw_xy = np.column_stack([raw_lidar.x, raw_lidar.y])
        for box, raw_box in zip(sample["boxes"], raw_boxes, strict=True):
            # the points of this box in the raw file (0.1 m LAS quantisation), then where the adapter put them
            offset = raw_xy - np.asarray(raw_box["position"][:2])
            c, s = math.cos(raw_box["yaw"]), math.sin(raw_box["yaw"])
            along, across = c * offset[:, 0] + s * offset[:, 1], -s * offset[:, 0] + c * offset[:, 1]
            mine = (np.abs(along) <= raw_box["extent"][0]) & (np.abs(across) <= raw_box["extent"][1])
            assert mine.sum() > 5
            offset = sample["lidar"][mine, :2] - box[:2]
            c, s = math.cos(box[6]), math.sin(box[6])
            along, across = c * offset[:, 0] + s * offset[:, 1], -s * offset[:, 0] + c * offset[:, 1]
            assert np.abs(along).max() <= box[3] / 2 + 1e-3 and np.abs(across).max() <= box[4] / 2 + 1e-3


def test_expected_points_is_a_plain_frame_change() -> None:
    """The test's own point helper: flip y and shift x by the rear-axle offset (no rotation without a view)."""
    np.testing.assert_allclose(expected_points(np.array([[10.0, 2.0]]), (0, 0, 0)), [[10.0 + REAR, -2.0]])


def _by_scenario(samples: list[dict], scenario: str, rig: str = "normal") -> list[dict]:
    chosen = [s for s in samples if s["meta"]["log_id"].startswith(scenario)]
    chosen = [s for s in chosen if s["meta"]["extras"]["carla_lead"]["rig"] == rig]
    return sorted(chosen, key=lambda s: s["meta"]["frame_idx"])


def test_left_turn_positive_right_turn_negative_stop_standstill(converted: tuple[Path, Path, list[dict]]) -> None:
    _, _, samples = converted
    left = _by_scenario(samples, "SignalizedJunctionLeftTurn")
    right = _by_scenario(samples, "SignalizedJunctionRightTurn")
    stop = _by_scenario(samples, "PedestrianCrossing")
    assert left[0]["future"][-1, 2] > 2.0 and left[0]["future"][-1, 3] > 0.5
    assert right[0]["future"][-1, 2] < -2.0 and right[0]["future"][-1, 3] < -0.5
    assert max(s["meta"]["ego"]["yaw_rate"] for s in left) > 0.5
    assert min(s["meta"]["ego"]["yaw_rate"] for s in right) < -0.5
    assert max(s["meta"]["ego"]["acceleration"][1] for s in left) > 3.0  # centripetal, towards the left
    assert Command.LEFT in {s["meta"]["ego"]["command"] for s in left}
    assert Command.RIGHT in {s["meta"]["ego"]["command"] for s in right}
    assert stop[0]["meta"]["ego"]["speed"] > 5.0
    assert stop[-1]["meta"]["ego"]["speed"] == pytest.approx(0.0, abs=0.05)
    assert np.abs(stop[-1]["future"][:, 1:3]).max() < 0.05  # standing still for the whole horizon
    assert min(s["meta"]["ego"]["acceleration"][0] for s in stop) < -2.0


def test_perturbated_rig_moves_labels_and_keys_differ(converted: tuple[Path, Path, list[dict]]) -> None:
    src, _, samples = converted
    keys = [s["__key__"] for s in samples]
    assert len(set(keys)) == len(keys)
    normal = {(s["meta"]["log_id"], s["meta"]["frame_idx"]): s for s in samples if "_perturbated_" not in s["__key__"]}
    for sample in samples:
        if "_perturbated_" not in sample["__key__"]:
            continue
        twin = normal[(sample["meta"]["log_id"], sample["meta"]["frame_idx"])]
        meta = raw(route_folder(src, sample), "metas", f"{sample['meta']['frame_idx']:04d}")
        # the rig is turned by +rotation in CARLA's clockwise yaw, so from it the real ego is turned by -rotation
        # clockwise, i.e. +rotation in ISO's counter-clockwise yaw
        now = sample["past"][-1]
        assert now[3] == pytest.approx(math.radians(meta["perturbation_rotation"]), abs=1e-5)
        assert np.hypot(*(now[1:3] - twin["past"][-1, 1:3])) > 0.05
        assert sample["cam_carla_mosaic"] != twin["cam_carla_mosaic"]


def test_manifest_info_and_camera_calibration(converted: tuple[Path, Path, list[dict]]) -> None:
    _, out, samples = converted
    manifest = load_manifest(out)
    assert manifest.num_rows == len(samples)
    assert all(manifest["has_lidar"].to_pylist())
    info = load_info(out)
    assert info["future"] == {"rate_hz": 20.0, "horizon_s": 3.0} and info["rig"] == "both"
    cameras = samples[0]["meta"]["cameras"]
    assert [c["tile"] for c in cameras] == [[0, 384], [384, 384], [768, 384]]
    for camera, side in zip(cameras, (1, 0, -1), strict=True):
        cam_to_ego = np.asarray(camera["cam_to_ego"])
        axis = cam_to_ego[:3, 2]  # optical axis in the ego frame
        assert axis[0] > 0.5 and np.sign(round(axis[1], 6)) == side
        ahead = cam_to_ego @ np.array([0.0, 0.0, 10.0, 1.0])  # 10 m along the optical axis
        point = np.linalg.inv(cam_to_ego) @ ahead
        pixel = np.asarray(camera["K"]) @ point[:3]
        np.testing.assert_allclose(pixel[:2] / pixel[2], [192.0, 192.0])
    assert cameras[1]["K"][0][0] == pytest.approx(192 / math.tan(math.radians(30)))


def test_hdmap_pixel_to_ego_matches_the_route(converted: tuple[Path, Path, list[dict]]) -> None:
    """Road pixels of the BEV lie on the converted route: the stored orientation and affine agree."""
    _, _, samples = converted
    for sample in _by_scenario(samples, "SignalizedJunctionLeftTurn")[:3]:
        affine = np.asarray(sample["meta"]["bev"]["pixel_to_ego"])
        rows, cols = np.nonzero(sample["bev_semantic"] == 4)  # lane markers along the path centre
        centres = np.column_stack([cols, rows, np.ones(len(rows))]) @ affine.T
        route = sample["route"]
        distance = np.min(np.linalg.norm(centres[:, None] - route[None], axis=2), axis=1)
        near = np.linalg.norm(centres - [REAR, 0], axis=1) < 40
        assert np.median(distance[near]) < 1.0


def test_box_classes(converted: tuple[Path, Path, list[dict]]) -> None:
    _, _, samples = converted
    classes = [c for sample in samples for c in sample["boxes"][:, 9].astype(int).tolist()]
    native = [n for sample in samples for n in sample["meta"]["extras"]["carla_lead"]["box_classes"]]
    want = {"walker": BoxClass.PEDESTRIAN, "traffic_light": BoxClass.TRAFFIC_LIGHT, "static": BoxClass.TRAFFIC_CONE}
    for cls, name in zip(classes, native, strict=True):
        if name in want:
            assert cls == want[name]
    assert BoxClass.EMERGENCY_VEHICLE in classes and BoxClass.VEHICLE in classes


def _write_lzma_pickle(path: Path, obj: object) -> None:
    with lzma.open(path, "wb") as file:
        pickle.dump(obj, file)


def test_bad_files_fail_their_route_only(tmp_path: Path) -> None:
    src, out = tmp_path / "src", tmp_path / "out"
    synth.generate(src, count=4, seed=2, frames=4)
    routes = sorted((src / "data").glob("*/*"))
    (routes[0] / "lidar" / "0002.laz").write_bytes(b"LASF" + b"\x00" * 300)
    meta = routes[1] / "metas" / "0001.pkl"
    meta.write_bytes(meta.read_bytes()[:200])
    _write_lzma_pickle(routes[2] / "bboxes" / "0003.pkl", [OrderedDict(a=1)])
    result = convert(CarlaLeadAdapter(), src, out)
    assert result.logs_converted == 1 and result.samples == 4
    errors = [json.loads(line) for line in (out / "errors.jsonl").read_text().splitlines()]
    by_log = {e["log"]: e["error"] for e in errors}
    assert "lidar/0002.laz" in by_log[f"{routes[0].parent.name}/{routes[0].name}"]
    assert "metas/0001.pkl" in by_log[f"{routes[1].parent.name}/{routes[1].name}"]
    message = by_log[f"{routes[2].parent.name}/{routes[2].name}"]
    assert "bboxes/0003.pkl" in message and "collections.OrderedDict" in message


def test_unpickler_never_runs_code(tmp_path: Path) -> None:
    class Evil:
        def __reduce__(self) -> tuple:
            return (print, ("pwned",))

    path = tmp_path / "0000.pkl"
    _write_lzma_pickle(path, {"speed": Evil()})
    with pytest.raises(LeadFormatError, match=r"builtins\.print"):
        read_pickle(path)


def test_a_missing_numeric_field_is_named_missing_not_unnumeric() -> None:
    path = Path("0000.json.gz")
    with pytest.raises(LeadFormatError, match=r"^0000\.json\.gz \(field 'speed'\): required field is missing$"):
        array({"steer": 0.0}, "speed", path)
    with pytest.raises(LeadFormatError, match=r"\(field 'speed'\): not numeric"):
        array({"speed": "fast"}, "speed", path)


values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**40), 2**40) | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)


@settings(max_examples=40, deadline=None)
@given(values, st.sampled_from(["float16", "float32", "float64", "int64", "uint8", "bool"]))
def test_unpickler_reads_every_builtin_and_numpy_value(tmp_path_factory: pytest.TempPathFactory, value, dtype) -> None:
    path = tmp_path_factory.mktemp("pkl") / "x.pkl"
    arr = np.arange(6).reshape(2, 3).astype(dtype)
    synth.write_pickle(path, {"value": value, "array": arr, "scalar": arr.ravel()[1], "set": {1, 2}})
    loaded = read_pickle(path)
    assert loaded["value"] == value and loaded["set"] == {1, 2}
    assert loaded["array"].dtype == arr.dtype and np.array_equal(loaded["array"], arr)
    assert loaded["scalar"] == arr.ravel()[1] and type(loaded["scalar"]) is type(arr.ravel()[1])


def test_failed_and_unfinished_routes_are_skipped_with_a_reason(tmp_path: Path) -> None:
    src = tmp_path / "src"
    synth.generate(src, count=3, seed=3, frames=3)
    routes = sorted((src / "data").glob("*/*"))
    (routes[0] / "results.json").unlink()
    failed = json.loads((routes[1] / "results.json").read_text())
    failed.update(status="Failed - Agent got blocked", scores={"score_composed": 40.0})
    failed["infractions"]["collisions_vehicle"] = ["hit a car"]
    (routes[1] / "results.json").write_text(json.dumps(failed))
    result = convert(CarlaLeadAdapter(), src, tmp_path / "out")
    reasons = {s["log"].split("/")[1]: s["reason"] for s in result.skipped}
    assert "no results.json" in reasons[routes[0].name]
    assert "Failed - Agent got blocked" in reasons[routes[1].name]
    assert result.ok and result.logs_converted == 1
    kept = convert(CarlaLeadAdapter(keep_failed=True), src, tmp_path / "out2")
    assert kept.logs_converted == 2 and len(kept.skipped) == 1  # without results.json LEAD never finished the route


def test_partial_route_converts_with_has_flags_false(tmp_path: Path) -> None:
    src = tmp_path / "src"
    synth.generate(src, count=1, seed=4, frames=3)
    route = next((src / "data").glob("*/*"))
    for folder in ("radar", "depth", "semantics", "lidar"):
        shutil.rmtree(route / folder)
    result = convert(CarlaLeadAdapter(), src, tmp_path / "out")
    assert result.ok and result.samples == 3
    samples = sorted(read_samples(tmp_path / "out"), key=lambda s: s["meta"]["frame_idx"])
    for sample in samples:
        has = sample["meta"]["has"]
        assert has["radar"] is False and has["depth_carla_mosaic"] is False and has["semantic_carla_mosaic"] is False
        assert has["lidar"] is False and "radar" not in sample and "depth_carla_mosaic" not in sample
        assert has["cam_carla_mosaic"] and has["bev_semantic"]
    # a sensor folder that holds other frames but not this one is damage, not a sensor the route lacks
    synth.generate(tmp_path / "src2", count=1, seed=4, frames=3)
    missing = next((tmp_path / "src2" / "data").glob("*/*")) / "lidar" / "0001.laz"
    missing.unlink()
    (error,) = convert(CarlaLeadAdapter(), tmp_path / "src2", tmp_path / "out2").errors
    assert f"{missing}: missing: the route's lidar/ folder holds other frames" in error["error"]


def test_options_split_skip_and_rig_validation(tmp_path: Path) -> None:
    src = tmp_path / "src"
    synth.generate(src, count=2, seed=5, frames=5)
    adapter = CarlaLeadAdapter(heldout_towns="Town13", skip_first=1, skip_last=2)
    logs = adapter.list_logs(src)
    assert {log.extra["town"]: log.split for log in logs} == {"Town12": "train", "Town13": "val"}
    assert [s["meta"]["frame_idx"] for s in adapter.iter_samples(logs[0])] == [1, 2]
    assert len(adapter.list_logs(src / "data")) == 2
    with pytest.raises(ValueError, match="rig must be one of"):
        CarlaLeadAdapter(rig="sideways")


def test_hdmap_affine_maps_the_centre_pixel_to_the_vehicle_centre() -> None:
    affine = np.asarray(hdmap_pixel_to_ego())
    np.testing.assert_allclose(affine @ [127.5, 127.5, 1.0], [REAR, 0.0])
    np.testing.assert_allclose(affine @ [127.5, 127.5 - 20, 1.0], [REAR + 10.0, 0.0])  # 20 px up = 10 m ahead
    np.testing.assert_allclose(affine @ [127.5 - 20, 127.5, 1.0], [REAR, 10.0])  # 20 px left = 10 m left
    assert len(camera_calibration()) == 3


def test_synth_cli(tmp_path: Path) -> None:
    cli = pytest.importorskip("lead_s2r.cli")
    cli.main(["synth", "carla_lead", "--out", str(tmp_path), "--routes", "1"])
    routes = list((tmp_path / "data").glob("*/*"))
    assert len(routes) == 1 and len(list((routes[0] / "rgb").glob("*.jpg"))) == 16


#: LEAD's rigs as its config lists them: tiles, tile width, stored rows, horizontal fov, principal row (the rendered
#: height / 2: LEAD keeps the top rows), CARLA yaw of each tile left to right.
LEAD_RIGS = {
    "CARLA_LEADERBOARD2_3CAMERAS": (3, 384, 384, 60.0, 192.0, [-54.5, 0.0, 54.5]),
    "CARLA_LEADERBOARD2_6CAMERAS": (6, 384, 384, 60.0, 192.0, [-57.5, 0.0, 57.5, -122.5, 180.0, 122.5]),
    "CARLA_PY123D_1CAMERA": (1, 1024, 384, 110.0, 256.0, [0.0]),
    "NAVSIM_4CAMERAS": (4, 480, 270, 63.71, 140.0, [-56.01, -1.03, 54.26, 180.0]),
}


def test_every_lead_camera_rig_converts_with_its_own_calibration(tmp_path: Path) -> None:
    src, out = tmp_path / "src", tmp_path / "out"
    synth.generate(src, count=4, seed=6, frames=2, rigs=tuple(LEAD_RIGS))
    result = convert(CarlaLeadAdapter(), src, out)
    assert result.ok and result.samples == 8, result.errors
    seen = set()
    for sample in read_samples(out):
        rig = sample["meta"]["extras"]["carla_lead"]["target_dataset"]
        seen.add(rig)
        tiles, width, height, fov, cy, yaws = LEAD_RIGS[rig]
        route, name = route_folder(src, sample), f"{sample['meta']['frame_idx']:04d}"
        assert sample["cam_carla_mosaic"] == (route / "rgb" / f"{name}.jpg").read_bytes()
        image = cv2.imdecode(np.frombuffer(sample["cam_carla_mosaic"], np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (height, tiles * width, 3)
        assert sample["semantic_carla_mosaic"].shape == (height, tiles * width)
        cameras = sample["meta"]["cameras"]
        assert [c["tile"] for c in cameras] == [[i * width, width] for i in range(tiles)]
        assert all(c["width"] == width and c["height"] == height for c in cameras)
        for camera, yaw in zip(cameras, yaws, strict=True):
            K = np.asarray(camera["K"])
            assert K[0, 0] == pytest.approx(width / 2 / math.tan(math.radians(fov / 2)))
            assert (K[0, 2], K[1, 2]) == (width / 2, cy)
            axis = np.asarray(camera["cam_to_ego"])[:3, 2]  # optical axis: CARLA's clockwise yaw, negated in ISO
            np.testing.assert_allclose(
                axis, [math.cos(math.radians(yaw)), -math.sin(math.radians(yaw)), 0.0], atol=1e-9
            )
    assert seen == set(LEAD_RIGS)


def test_each_rig_is_laid_out_in_ltfv6_by_its_calibration(tmp_path: Path) -> None:
    """Only the NAVSIM-matched rig fills LTFv6's 1920x270 input; the others are letterboxed, never squashed."""
    from lead_s2r.data.transforms import SourceTransform
    from lead_s2r.models.lead_config import LeadConfig

    for rig, (tiles, width, height, *_) in LEAD_RIGS.items():
        cameras = camera_calibration(rig)
        ltfv6 = LeadConfig(use_navsim_data=True, LTF=True, use_planning_decoder=True)
        transform = SourceTransform("carla", input_spec(ltfv6), ["carla_mosaic"])
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            layout = transform.camera.plan_for({"cameras": cameras}, [(height, tiles * width)]).layout
        assert layout.letterboxed == (rig != "NAVSIM_4CAMERAS") == bool(caught), rig
        if rig == "NAVSIM_4CAMERAS":  # nuPlan's 38.5 deg around the principal row 140: rows [5, 275)
            assert {(b.top, b.bottom) for b in layout.bands[0]} == {(5, 275)}


def rewrite_meta(route: Path, name: str, **dataset_information: object) -> None:
    meta = raw(route, "metas", name)
    if dataset_information:
        meta["dataset_information"].update(dataset_information)
    else:
        del meta["dataset_information"]
    synth.write_pickle(route / "metas" / f"{name}.pkl", meta)


def test_the_rig_comes_from_the_meta_and_a_wrong_one_is_refused(tmp_path: Path) -> None:
    src = tmp_path / "src"
    synth.generate(src, count=4, seed=7, frames=1, rigs=("CARLA_LEADERBOARD2_3CAMERAS", "CARLA_LEADERBOARD2_6CAMERAS"))
    three, six, unknown, wrong = sorted((src / "data").glob("*/*"), key=lambda p: int(p.name.split("_")[2]))
    rewrite_meta(three, "0000")  # no dataset_information: LEAD's default 3-camera rig
    rewrite_meta(six, "0000", target_dataset=2)  # LEAD's enum number
    rewrite_meta(unknown, "0000", target_dataset="WAYMO_E2E_2025_3CAMERAS")
    rewrite_meta(wrong, "0000", target_dataset="NAVSIM_4CAMERAS")  # a 6-camera mosaic
    result = convert(CarlaLeadAdapter(), src, tmp_path / "out")
    assert not result.ok and result.logs_converted == 2
    rigs = {
        s["meta"]["log_id"]: s["meta"]["extras"]["carla_lead"]["target_dataset"] for s in read_samples(tmp_path / "out")
    }
    assert set(rigs.values()) == {"CARLA_LEADERBOARD2_3CAMERAS", "CARLA_LEADERBOARD2_6CAMERAS"} and len(rigs) == 2
    errors = {e["log"].split("/")[1]: e["error"] for e in map(json.loads, (tmp_path / "out" / "errors.jsonl").open())}
    assert "metas/0000.pkl" in errors[unknown.name] and "dataset_information.target_dataset" in errors[unknown.name]
    assert "WAYMO_E2E_2025_3CAMERAS" in errors[unknown.name]
    assert "rgb/0000.jpg" in errors[wrong.name] and "mosaic is 2304x384" in errors[wrong.name]


def test_a_mosaic_stored_uncropped_keeps_its_principal_row(tmp_path: Path) -> None:
    """LEAD renders the NAVSIM-matched tiles 280 rows high and keeps the top 270; a full-height mosaic is accepted too,
    with the same principal row (the rendered centre), and any other size names the rig."""
    from lead_s2r_adapters.carla_lead import mosaic_height

    full = cv2.imencode(".jpg", np.zeros((280, 1920, 3), np.uint8))[1].tobytes()
    assert mosaic_height(full, "NAVSIM_4CAMERAS", tmp_path / "0000.jpg") == 280
    cameras = camera_calibration("NAVSIM_4CAMERAS", 280)
    assert cameras[0]["height"] == 280 and cameras[0]["K"][1][2] == 140.0
    with pytest.raises(LeadFormatError, match=r"0000\.jpg.*1920x280.*CARLA_LEADERBOARD2_3CAMERAS .*stores 1152x384"):
        mosaic_height(full, "CARLA_LEADERBOARD2_3CAMERAS", tmp_path / "0000.jpg")


def test_realistic_frames_are_as_heavy_as_leads_and_convert(tmp_path: Path) -> None:
    """``realistic=True``: 5 sweeps x 10,000 points plus 10 steps x 300 radar returns (duplicated 5x within 32 m),
    65 actors with futures, every planner LEAD saves with its GNSS twin; the adapter converts it like a light frame."""
    synth.generate(tmp_path, count=1, frames=1, realistic=True)
    folder = next((tmp_path / "data").glob("*/*"))
    las = laspy.read(str(folder / "lidar" / "0000.laz"))
    per_step = np.bincount(np.asarray(las["time"]), minlength=10)  # LiDAR sweeps 0..4 and radar steps 0..9 share it
    radar = per_step[5:]  # steps 5..9 hold radar returns only: 300 each, plus up to 4 duplicates within 32 m
    assert len(per_step) == 10 and ((radar >= 300) & (radar <= 1_500)).all()
    assert ((per_step[:5] >= 9_500 + 300) & (per_step[:5] <= 10_000 + 1_500)).all()  # a sweep + a radar step each
    assert 55_000 < len(las.x) < 70_000
    boxes = read_pickle(folder / "bboxes" / "0000.pkl")
    assert len(boxes) == 1 + 5 + sum(count for *_, count in synth.STREET)
    assert sum(box.get("future_positions") is not None for box in boxes) >= 40
    meta = read_pickle(folder / "metas" / "0000.pkl")
    for distance in (3.0, 3.25, 7.0, 10.0):
        assert f"next_target_points_{distance}" in meta and f"next_gps_target_points_{distance}" in meta
    with np.load(folder / "radar" / "0000.npz") as radar:
        assert sum(len(radar[f"radar{i}"]) for i in range(1, 5)) == 4 * carla_lead_sensors.RADAR_POINTS_PER_SENSOR
    convert(CarlaLeadAdapter(), tmp_path, tmp_path / "out")
    samples = list(read_samples(tmp_path / "out"))
    assert len(samples) == 1 and len(samples[0]["lidar"]) == len(las.x)  # every point kept
