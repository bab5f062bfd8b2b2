"""The synthetic worlds where perception matters: pedestrians stand in the lane ahead in a third of the NAVSIM logs
and WOD-E2E segments (and in CARLA's stop routes), the cameras show them, the boxes hold them, the driver stops
behind them, the ego status does not give them away, and the tag that marks them survives conversion and selects
exactly the samples a "needs perception" column scores."""

import pickle
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pyarrow.parquet as pq
import pytest

from lead_s2r.cli import main
from lead_s2r.convert import convert
from lead_s2r.registry import get_adapter
from lead_s2r.scoring import run
from lead_s2r.scoring.run import choose_samples, planner_predictions, score_predictions
from lead_s2r.shards import load_manifest, read_samples
from lead_s2r.synthetic import carla_lead, pedestrians_ahead, wod_e2e
from lead_s2r.synthetic import navsim as synth
from lead_s2r_adapters.carla_lead_io import read_pickle

TAG = "scene_filter:pedestrians_ahead"
#: Six logs: the three base logs, then a cruise and a slow drive with pedestrians (3 and 5) and a turn (4).
LOGS = 6


def is_pedestrian(pixels: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of a decoded BGR image drawn in the pedestrians' colour (JPEG moves it a little)."""
    return (np.abs(pixels.astype(int) - pedestrians_ahead.COLOUR).max(axis=-1) < 60) & (pixels[..., 1] > 150)


@pytest.fixture(scope="module")
def navsim_world(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    raw, data = tmp_path_factory.mktemp("navsim_raw"), tmp_path_factory.mktemp("navsim_data")
    synth.generate(raw, splits={"test": LOGS})
    tag_filters = str(raw / "scene_filters" / "pedestrians_ahead.yaml")
    adapter = get_adapter("navsim", maps=str(raw / "maps"), tag_filters=tag_filters)
    assert convert(adapter, raw, data, workers=1, force=True, progress=False).ok
    return raw, data


def _frames(raw: Path, spec: synth.LogSpec) -> list[dict]:
    return pickle.loads((raw / "navsim_logs" / "test" / f"{spec.name}.pkl").read_bytes())


def test_a_third_of_the_logs_have_pedestrians_ahead_on_straight_routes_only() -> None:
    specs = synth.log_specs(52)
    braking = [i for i, spec in enumerate(specs) if spec.brake_at is not None]
    assert braking[:4] == [3, 5, 9, 11] and len(braking) == 17  # a third, dealt evenly over consecutive splits
    assert sum(i >= 32 for i in braking) == 7  # 7 of the quickstart's 20 held-out logs (logs 32-51)
    assert all(synth.LEFT_TURN not in specs[i].lanes for i in braking)


def test_the_pedestrians_stand_in_the_lane_ahead_and_the_driver_stops_behind_them(navsim_world) -> None:
    raw, _ = navsim_world
    for spec in (s for s in synth.log_specs(LOGS) if s.brake_at is not None):
        frames = _frames(raw, spec)
        for frame in frames:
            anns = frame["anns"]
            ahead = anns["gt_boxes"][anns["gt_names"] == "pedestrian"]
            ahead = ahead[np.abs(ahead[:, 1]) < 2.0]  # in the ego lane (half width 1.75 m)
            assert len(ahead) == len(pedestrians_ahead.ROW) and (ahead[:, 0] > 0).all()
            assert "vehicle" not in anns["gt_names"][np.abs(anns["gt_boxes"][:, 1]) < 2.0]  # no lead car in between
            gap = ahead[:, 0].min() - pedestrians_ahead.SIZE[0] / 2 - synth.EGO_FRONT
            assert gap > pedestrians_ahead.GAP - 0.05  # never closer than the gap: no collision
        speeds = [frame["ego_dynamic_state"][0] for frame in frames]
        assert speeds[-1] < 1.0 and gap < pedestrians_ahead.GAP + 0.5  # stopped (or all but) behind them
        braking = [f["ego_dynamic_state"][2] for f in frames if f["timestamp"] - frames[0]["timestamp"] > 5.5e6]
        assert min(braking) < -1.5 and max(braking) <= 0.0


def test_the_ego_status_of_every_scene_is_that_of_a_log_without_pedestrians(navsim_world) -> None:
    """Up to the last scene's current frame (4.5 s) the log is the same drive as its twin without pedestrians."""
    last_scene = synth.FRAMES - synth.FUTURE - 1
    for spec in (s for s in synth.log_specs(LOGS) if s.brake_at is not None):
        with_them, without = synth.ego_states(spec), synth.ego_states(replace(spec, brake_at=None))
        for name in ("poses", "dynamics"):
            np.testing.assert_allclose(with_them[name][: last_scene + 1], without[name][: last_scene + 1])
        assert not np.allclose(with_them["poses"][-1], without["poses"][-1])  # the futures differ


def test_the_front_camera_shows_the_pedestrians(navsim_world) -> None:
    raw, _ = navsim_world
    for spec in synth.log_specs(LOGS)[3:]:
        frame = _frames(raw, spec)[synth.FRAMES - synth.FUTURE - 1]  # the last scene's current frame
        path = raw / "sensor_blobs" / "test" / frame["cams"]["CAM_F0"]["data_path"]
        image = cv2.imread(str(path))
        centre = image[:, image.shape[1] // 2 - 12 : image.shape[1] // 2 + 12]  # the lane ahead
        seen = is_pedestrian(centre).sum()
        assert seen >= 12 if spec.brake_at is not None else seen == 0, spec.name


def test_the_tag_survives_conversion_on_exactly_the_pedestrian_logs(navsim_world) -> None:
    _, data = navsim_world
    pedestrian_logs = {s.name for s in synth.log_specs(LOGS) if s.brake_at is not None}
    manifest = load_manifest(data).to_pylist()
    tagged = {row["log"] for row in manifest if row["tags"] == [TAG]}
    assert tagged == pedestrian_logs
    assert all(row["tags"] == [] for row in manifest if row["log"] not in pedestrian_logs)
    assert all(sample["meta"]["tags"] == [TAG] for sample in read_samples(data) if sample["meta"]["log_id"] in tagged)


def test_needs_perception_scores_exactly_the_tagged_samples(navsim_world, tmp_path: Path) -> None:
    """The tagged scoring is the whole scoring restricted to the tagged samples; there, the logged human keeps its
    score while a driver who keeps its speed (what the ego status alone suggests) runs into the pedestrians."""
    _, data = navsim_world
    tagged = {row["key"] for row in load_manifest(data).to_pylist() if TAG in row["tags"]}
    means = {}
    for planner in ("human", "constant-velocity"):
        predictions = planner_predictions(planner, data, tmp_path / f"{planner}.parquet")
        whole = score_predictions("pdms@navsim-1.1", predictions, data, tmp_path / planner, allow_missing=True)
        subset = score_predictions(
            "pdms@navsim-1.1", predictions, data, tmp_path / f"{planner}-tagged", tag=TAG, allow_missing=True
        )
        rows = pq.read_table(tmp_path / planner / "scores.parquet").to_pylist()
        subset_rows = pq.read_table(tmp_path / f"{planner}-tagged" / "scores.parquet").to_pylist()
        assert {row["key"] for row in subset_rows} == tagged and subset["tag"] == TAG and whole["tag"] is None
        expected = np.mean([row["score"] for row in rows if row["key"] in tagged])
        assert subset["aggregates"]["pdms"] == pytest.approx(expected)
        means[planner] = subset["aggregates"]
    assert means["human"]["pdms"] > 0.95 and means["human"]["no_at_fault_collisions"] == 1.0
    assert means["constant-velocity"]["no_at_fault_collisions"] < 0.75
    assert means["constant-velocity"]["pdms"] < means["human"]["pdms"] - 0.25


@pytest.fixture
def decoded(monkeypatch) -> list[str]:
    """The keys scoring decodes from the tars (:func:`~lead_s2r.shards.read_part`), in order."""
    keys: list[str] = []
    read_part = run.read_part

    def counting(shard, part, *args):
        keys.extend(part)
        return read_part(shard, part, *args)

    monkeypatch.setattr(run, "read_part", counting)
    return keys


def test_a_tag_decodes_only_the_tagged_samples_the_same_as_decoding_all(navsim_world, decoded) -> None:
    """The manifest says which samples carry the tag, so the others are never read from the tars."""
    _, data = navsim_world
    fields = ("future", "scoring")
    everything = {sample["__key__"]: sample for sample in read_samples(data, fields=fields)}
    chosen = choose_samples([data], fields, "test", tag=TAG)[0]
    tagged = [key for key, sample in everything.items() if TAG in sample["meta"]["tags"]]
    assert [sample["__key__"] for sample in chosen] == decoded == tagged and 0 < len(tagged) < len(everything)
    assert pickle.dumps(chosen) == pickle.dumps([everything[key] for key in tagged])  # decoded as read_samples does


def test_a_sample_cache_decodes_each_selection_once_and_scores_the_same_bytes(navsim_world, decoded, tmp_path) -> None:
    """The quickstart scores some twenty prediction sets against the same held-out samples: a SampleCache decodes
    each selection (fields, split, tag) once, and the samples it hands out again score as freshly decoded ones."""
    _, data = navsim_world
    predictions = planner_predictions("constant-velocity", data, tmp_path / "predictions.parquet")
    keys = load_manifest(data).to_pylist()
    decoded.clear()
    cache = run.SampleCache()

    def scored(name: str, **options) -> bytes:
        score_predictions("pdms@navsim-1.1", predictions, data, tmp_path / name, allow_missing=True, **options)
        return (tmp_path / name / "scores.parquet").read_bytes()

    cached = {(tag, i): scored(f"cached-{i}-{tag}", tag=tag, sample_cache=cache) for i in (0, 1) for tag in (None, TAG)}
    tagged = [row["key"] for row in keys if TAG in row["tags"]]
    assert decoded == [row["key"] for row in keys] + tagged  # the whole split once, the tagged samples once
    for tag in (None, TAG):
        assert cached[tag, 0] == cached[tag, 1] == scored(f"fresh-{tag}", tag=tag)


def test_score_cli_names_a_tag_no_sample_has(navsim_world, tmp_path: Path, capsys) -> None:
    _, data = navsim_world
    args = ["score", "--metric", "ade", "--planner", "human", "--data", str(data), "--out", str(tmp_path / "s")]
    assert main([*args, "--tag", "cluster:Pedestrian"]) == 2
    assert "--tag cluster:Pedestrian: no sample" in capsys.readouterr().err and not (tmp_path / "s").exists()
    assert main([*args, "--tag", TAG]) == 0


@pytest.fixture(scope="module")
def wod_world(tmp_path_factory: pytest.TempPathFactory) -> tuple[wod_e2e.SynthDataset, Path]:
    raw, data = tmp_path_factory.mktemp("wod_raw"), tmp_path_factory.mktemp("wod_data")
    dataset = wod_e2e.make_dataset(splits={"train": 2, "val": 6})
    wod_e2e.write_dataset(raw, dataset)
    assert convert(get_adapter("wod_e2e"), raw, data, workers=1, force=True, progress=False).ok
    return dataset, data


def test_wod_pedestrian_segments_brake_after_every_frame_and_carry_their_cluster(wod_world) -> None:
    dataset, data = wod_world
    segments: dict[str, list[wod_e2e.SynthFrame]] = {}
    for frame in dataset.frames:
        segments.setdefault(frame.sequence, []).append(frame)
    val = [frames for frames in segments.values() if frames[0].split == "val"]
    pedestrian = {frames[0].sequence for i, frames in enumerate(val) if wod_e2e.is_pedestrian_segment(i)}
    assert len(pedestrian) == 2 and {s for s, c in dataset.clusters.items() if c == "Pedestrian"} == pedestrian
    for frames in val:
        for frame in frames:
            if frame.sequence in pedestrian:
                speed = np.hypot(frame.past[:, 2], frame.past[:, 3])
                assert np.abs(np.diff(speed, 2)).max() < 1e-3  # the past: constant acceleration, no braking yet
                final = np.linalg.norm(frame.future[-1, :2] - frame.future[-2, :2]) / 0.25
                assert final < speed[-1] - 1.5  # the future: braking
            fronts = [c for c in frame.cameras if c.name in (1, 2, 3)]  # the three cameras the twins stitch
            seen = sum(
                is_pedestrian(cv2.imdecode(np.frombuffer(c.jpeg, np.uint8), cv2.IMREAD_COLOR)).sum() for c in fronts
            )
            assert seen >= 6 if frame.sequence in pedestrian else seen == 0
    tags = {s["meta"]["extras"]["wod_e2e"]["frame_name"][:32]: s["meta"]["tags"] for s in read_samples(data)}
    assert {sequence for sequence, t in tags.items() if t == ["cluster:Pedestrian"]} == pedestrian


def test_carla_stop_brakes_for_walkers_labelled_as_boxes_and_drawn_in_the_front_tile(tmp_path: Path) -> None:
    carla_lead.generate(tmp_path, count=3, frames=12)  # 2.75 s: the stop takes 2.5 s
    route = next((tmp_path / "data" / carla_lead.SCENARIOS["stop"]).iterdir())
    for name in ("0000", "0011"):
        boxes = read_pickle(route / "bboxes" / f"{name}.pkl")
        meta = read_pickle(route / "metas" / f"{name}.pkl")
        walkers = np.array([b["position"][:2] for b in boxes if b.get("type_id") == carla_lead.WALKER_AHEAD])
        assert len(walkers) == len(pedestrians_ahead.ROW) and (np.abs(walkers[:, 1]) < 2.0).all()
        assert meta["walker_hazard"] and not meta["light_hazard"]
        image = cv2.imread(str(route / "rgb" / f"{name}.jpg"))
        tile = image.shape[1] // 3
        assert is_pedestrian(image[:, tile : 2 * tile]).sum() > 50 and not is_pedestrian(image[:, :tile]).any()
    gap = walkers[:, 0].mean() - pedestrians_ahead.SIZE[0] / 2 - carla_lead.EGO_EXTENT[0]  # front bumper to them
    assert gap == pytest.approx(pedestrians_ahead.GAP, abs=0.2) and meta["speed"] == 0.0  # stopped behind them
