"""navhard two-stage: the synthetic split (nuPlan-object pickles) -> NAVSIM adapter -> samples -> two-stage math,
and end to end through ``lead-s2r score --metric epdms@navsim-2.2``."""

import csv
import importlib.util
import json
import pickle
import pickletools
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml

from lead_s2r.cli import main as cli_main
from lead_s2r.convert import convert
from lead_s2r.formats.foreign_pickle import ForeignClass, ForeignObject, dumps
from lead_s2r.formats.navsim_two_stage import TwoStageGroup, parse_mapping
from lead_s2r.geometry import to_global, to_local
from lead_s2r.predictions import write_predictions
from lead_s2r.schema import BoxClass
from lead_s2r.scoring.baselines import predict_constant_velocity
from lead_s2r.scoring.navsim.two_stage_samples import CSV_NAME
from lead_s2r.scoring.pdm import epdms, two_stage
from lead_s2r.scoring.pdm.epdms import FILTERED
from lead_s2r.scoring.pdm.state import STATE_SIZE
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim as synth
from lead_s2r.synthetic import navsim_map as synth_map
from lead_s2r.synthetic import navsim_navhard as hard
from lead_s2r.synthetic import pedestrians_ahead
from lead_s2r_adapters import navsim_synthetic
from lead_s2r_adapters.navsim import NavsimAdapter
from lead_s2r_adapters.navsim_io import NavsimFormatError


@pytest.fixture(scope="module")
def raw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("navhard_raw")
    assert cli_main(["synth", "navsim_navhard", "--out", str(out)]) == 0
    return out


def adapter(raw: Path) -> NavsimAdapter:
    return NavsimAdapter(
        split=hard.SPLIT,
        scene_filter=str(raw / "scene_filters" / f"{hard.SPLIT}.yaml"),
        maps=str(raw / "maps"),
        two_stage_mapping=str(raw / "train_test_split" / f"{hard.SPLIT}.yaml"),
    )


@pytest.fixture(scope="module")
def converted(raw: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("navhard_out")
    result = convert(adapter(raw), raw, out)
    assert result.ok, result.errors
    return out


@pytest.fixture(scope="module")
def samples(converted: Path) -> dict[str, dict]:
    return {s["meta"]["extras"]["navsim"]["scene_token"]: s for s in read_samples(converted)}


@pytest.fixture(scope="module")
def mapping(raw: Path) -> list[TwoStageGroup]:
    config = yaml.safe_load((raw / "train_test_split" / f"{hard.SPLIT}.yaml").read_text())
    return parse_mapping(config["reactive_all_mapping"])


def scene_paths(raw: Path) -> list[Path]:
    return sorted((raw / hard.SPLIT / "synthetic_scene_pickles").glob("*.pkl"))


def test_synthetic_pickles_name_nuplan_classes_and_no_nuplan_is_importable(raw: Path) -> None:
    assert importlib.util.find_spec("nuplan") is None
    data = scene_paths(raw)[0].read_bytes()
    globals_named = {arg for op, arg, _ in pickletools.genops(data) if op.name == "SHORT_BINUNICODE"}
    assert {"nuplan.common.actor_state.agent", "Agent", "nuplan.common.maps.maps_datatypes"} <= globals_named
    with pytest.raises(ModuleNotFoundError, match="nuplan"):
        pickle.loads(data)  # a plain unpickler needs nuPlan: the references are real


def test_restricted_reader_maps_nuplan_objects_to_plain_data(raw: Path) -> None:
    scene = navsim_synthetic.load_scene(scene_paths(raw)[0])
    assert len(scene["frames"]) == hard.HISTORY and len(scene["extended_detections_tracks"]) == hard.FUTURE
    objects = navsim_synthetic.tracked_objects(scene["extended_detections_tracks"][0], "test")
    assert set(objects.classes) >= {BoxClass.VEHICLE, BoxClass.PEDESTRIAN, BoxClass.TRAFFIC_CONE}
    cone = list(objects.classes).index(BoxClass.TRAFFIC_CONE)
    assert tuple(objects.velocity[cone]) == (0.0, 0.0) and tuple(objects.size[cone]) == pytest.approx((0.4, 0.4, 0.7))
    # frames 12..19 of every log: connector 2012 red, 2021 green
    assert navsim_synthetic.red_lights(scene["extended_traffic_light_data"][0], "test") == [2012]


def test_a_foreign_class_in_a_synthetic_scene_is_refused_by_name(tmp_path: Path) -> None:
    path = tmp_path / "bad.pkl"
    hostile = ForeignObject(ForeignClass("os", "system"), ("echo pwned",), reduce=True)
    path.write_bytes(dumps({key: [hostile] for key in navsim_synthetic.SCENE_KEYS}))
    with pytest.raises(NavsimFormatError, match=r"os\.system"):
        navsim_synthetic.load_scene(path)


def test_every_stage_one_and_stage_two_token_is_one_sample(samples: dict, mapping: list) -> None:
    tokens = {t for group in mapping for t in group.tokens()}
    assert set(samples) == tokens and len(tokens) == 3 * (2 + 2 * len(hard.OFFSETS))
    for group in mapping:
        for token, stage, role in [(group.original, 1, "original"), (group.previous, 1, "previous")] + [
            (t, 2, r) for pair in group.pairs for t, r in zip(pair, ("now", "previous"), strict=True)
        ]:
            extras, meta = samples[token]["meta"]["extras"]["navsim"], samples[token]["meta"]
            assert (extras["stage"], extras["two_stage_role"], meta["is_synthetic"]) == (stage, role, stage == 2)
            assert extras["two_stage_group"][0] == group.original


def test_info_keeps_the_whole_mapping(converted: Path, raw: Path) -> None:
    info = json.loads((converted / "info.json").read_text())
    config = yaml.safe_load((raw / "train_test_split" / f"{hard.SPLIT}.yaml").read_text())
    blob = json.dumps(info)
    assert all(token in blob for entry in config["reactive_all_mapping"] for token in entry[:2])
    assert "reactive_all_mapping" in blob


def spec_of(log_name: str) -> synth.LogSpec:
    return next(spec for spec in synth.log_specs(None) if spec.name == log_name)


def test_synthetic_sample_geometry_matches_the_generator(samples: dict, mapping: list) -> None:
    group = mapping[0]
    sample = samples[group.pairs[2][0]]  # "now" variant shifted 1.2 m to the left
    spec = spec_of(sample["meta"]["log_id"])
    truth = hard.shifted_pose(synth.ego_states(spec)["poses"][hard.ORIGINAL_FRAME + hard.FUTURE], hard.OFFSETS[2])
    origin = sample["scoring"]["origin"]
    np.testing.assert_allclose(origin[:2] - synth_map.ORIGIN, truth[:2], atol=1e-6)
    assert "future" not in sample and "lidar" not in sample and "cam_front" in sample
    np.testing.assert_allclose(sample["past"][-1], [0, 0, 0, 0], atol=1e-6)
    # the lead vehicle (box 0) 2 s later, in the shifted ego frame
    agents = synth.agents_for(spec, synth.ego_states(spec)["poses"][0])
    t = (hard.ORIGINAL_FRAME + hard.FUTURE + 4) * synth.DT_US / 1e6
    lead = np.r_[agents[0].centre(t), agents[0].yaw]
    np.testing.assert_allclose(sample["agents_future"]["poses"][0, 3], to_local(lead, truth), atol=1e-4)
    red = sample["scoring"]
    assert red["red_light_ids"][red["red_light_offsets"][1] : red["red_light_offsets"][2]].tolist() == [2012]
    assert sample["scoring"]["ego_past"].shape == (hard.HISTORY, 8)


def test_stage_one_samples_store_the_logged_past_dynamics(samples: dict, mapping: list, raw: Path) -> None:
    sample = samples[mapping[1].original]
    frames = pickle.loads((raw / hard.SPLIT / "openscene_meta_datas" / f"{sample['meta']['log_id']}.pkl").read_bytes())
    past = sample["scoring"]["ego_past"]
    np.testing.assert_allclose(past[:, 0], [-1.5, -1.0, -0.5, 0.0], atol=1e-6)
    np.testing.assert_allclose(past[-1, 1:4], 0.0, atol=1e-9)
    current = hard.ORIGINAL_FRAME
    expected = [frames[i]["ego_dynamic_state"] for i in range(current - 3, current + 1)]
    np.testing.assert_allclose(past[:, 4:], expected, atol=1e-9)
    np.testing.assert_allclose(past[:, 1:3], sample["past"][:, 1:3], atol=1e-5)


def rows_from_samples(samples: dict) -> list[two_stage.TokenRow]:
    """Stand-in scores (all 1) on the converted samples' start points, planned endpoints (the logged future's end
    for stage 1) and times: what the two-stage math needs from a conversion."""
    rows = []
    for token, sample in samples.items():
        origin = sample["scoring"]["origin"]
        end = to_global(sample["future"][-1, 1:], origin)[:2] if "future" in sample else origin[:2]
        rows.append(
            two_stage.TokenRow(
                token,
                dict.fromkeys(FILTERED, 1.0),
                sample["meta"]["timestamp_us"] / 1e6,
                origin[:2],
                end,
                np.zeros((41, STATE_SIZE)),
            )
        )
    return rows


def no_features(states: np.ndarray, time: np.ndarray) -> dict[str, np.ndarray]:
    return {name: np.zeros(len(time)) for name in ("acceleration", "jerk", "yaw_rate", "yaw_accel")}


def test_converted_split_aggregates_two_stage(samples: dict, mapping: list) -> None:
    result = two_stage.two_stage_aggregate(rows_from_samples(samples), mapping, no_features)
    raw = np.exp(-np.square(hard.OFFSETS) / 0.2)  # the logged endpoint is the unshifted synthetic start
    for group in mapping:
        weights = [result.per_token[now]["weight"] for now, _ in group.pairs]
        assert weights == pytest.approx(raw / raw.sum(), abs=1e-6)
    assert result.combined["score"] == pytest.approx(1.0) and result.stage_two["score"] == pytest.approx(1.0)


def test_a_missing_stage_two_token_fails_with_its_name(samples: dict, mapping: list) -> None:
    dropped = mapping[2].pairs[1][1]
    rows = [row for row in rows_from_samples(samples) if row.token != dropped]
    with pytest.raises(KeyError, match=dropped):
        two_stage.two_stage_aggregate(rows, mapping, no_features)


def test_a_filter_token_without_a_synthetic_pickle_is_reported(raw: Path, tmp_path: Path) -> None:
    config = yaml.safe_load((raw / "scene_filters" / f"{hard.SPLIT}.yaml").read_text())
    config["reactive_synthetic_initial_tokens"].append("0123456789abcdef0")
    broken = tmp_path / "filter.yaml"
    broken.write_text(yaml.safe_dump(config))
    checker = NavsimAdapter(split=hard.SPLIT, scene_filter=str(broken))
    checker.list_logs(raw)
    (bad,) = checker.bad_records()
    assert bad["scene_filter"] == str(broken) and "0123456789abcdef0" in bad["error"]


# --------------------------------------------------------------------------- scored end to end


@pytest.fixture(scope="module")
def scored(converted: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``lead-s2r score`` of NAVSIM's constant-velocity agent on every stage-1 and stage-2 token."""
    out = tmp_path_factory.mktemp("navhard_scores")
    args = ["score", "--metric", "epdms@navsim-2.2", "--planner", "constant-velocity", "--data", str(converted)]
    assert cli_main([*args, "--out", str(out), "--reference-cache", str(out.parent / "navhard_references")]) == 0
    return out


def scored_rows(scored: Path) -> dict[str, dict]:
    return {row["token"]: row for row in pq.read_table(scored / "scores.parquet").to_pylist()}


def test_scored_split_reports_navsim_two_stage_summaries_and_log_replay(scored: Path) -> None:
    report = json.loads((scored / "scores.json").read_text())
    aggregates, config = report["aggregates"], report["config"]
    assert (aggregates["groups"], aggregates["frames_stage_one"], aggregates["frames_stage_two"]) == (3, 6, 18)
    assert aggregates["epdms"] == aggregates["extended_pdm_score_combined"]
    assert config["scored_two_stage"] and config["traffic_agents"] == "log_replay"
    assert "reactive" in config["known_difference"]
    rows = scored_rows(scored)
    assert all(np.isfinite(row[epdms.EC]) for row in rows.values())  # every frame has its pair
    # CV keeps every rule on the stage-1 frames (each log still drives straight on behind its lead car, which keeps
    # its gap); 4 s later the turning log's ego is at the junction and CV goes straight on, off the road
    stage_one, stage_two = (aggregates[f"extended_pdm_score_stage_{n}_columns"] for n in ("one", "two"))
    assert all(stage_one[name] == 1.0 for name in (epdms.NC, epdms.DAC, epdms.DDC, epdms.TLC, epdms.TTC, epdms.LK))
    assert stage_two[epdms.NC] == 1.0 and stage_two[epdms.DAC] < 1.0


def test_stage_two_weights_measure_from_the_planned_endpoint(scored: Path, samples: dict, mapping: list) -> None:
    rows, fallbacks = scored_rows(scored), 0
    for group in mapping:
        for side, first in enumerate((group.original, group.previous)):
            plan = predict_constant_velocity(samples[first])
            endpoint = to_global(np.r_[plan.xy[-1], plan.yaw[-1]], samples[first]["scoring"]["origin"])[:2]
            variants = [pair[side] for pair in group.pairs]
            starts = np.array([samples[t]["scoring"]["origin"][:2] for t in variants])
            raw = np.exp(-np.sum((starts - endpoint) ** 2, axis=1) / 0.2)
            expected = raw / raw.sum() if raw.sum() > 1e-8 else np.full(len(raw), 1 / len(raw))
            fallbacks += raw.sum() <= 1e-8
            assert [rows[t]["weight"] for t in variants] == pytest.approx(expected, abs=1e-9)
    assert 0 < fallbacks < 2 * len(mapping)  # CV goes straight on through the turn: far from every start there


def test_combined_is_the_group_mean_of_weighted_stage_products(scored: Path, mapping: list) -> None:
    rows = scored_rows(scored)
    aggregates = json.loads((scored / "scores.json").read_text())["aggregates"]
    for column in (*two_stage.SCORE_COLUMNS[:-1], "score"):
        groups = []
        for group in mapping:
            sides = []
            for side, first in enumerate((group.original, group.previous)):
                variants = [rows[pair[side]] for pair in group.pairs]
                stage_two = sum(v["weight"] * v[column] for v in variants) / sum(v["weight"] for v in variants)
                sides.append(rows[first][column] * stage_two)
            groups.append(sum(sides) / 2)
        assert aggregates["extended_pdm_score_combined_columns"][column] == pytest.approx(np.mean(groups), abs=1e-12)


def test_two_stage_csv_has_navsims_layout(scored: Path, mapping: list) -> None:
    with open(scored / CSV_NAME) as file:
        rows = list(csv.reader(file))
    header = rows[0]
    assert header[:3] == ["", "token", "valid"] and header[-1] == "score"
    assert header[3:5] == ["no_at_fault_collisions_stage_one", "drivable_area_compliance_stage_one"]
    assert "two_frame_extended_comfort_stage_two" in header
    assert [row[1] for row in rows[-3:]] == list(two_stage.SUMMARY_TOKENS)
    assert len(rows) == 1 + 24 + 3 and [row[0] for row in rows[1:]] == [str(i) for i in range(27)]
    original = next(row for row in rows if row[1] == mapping[0].original)
    assert original[header.index("ego_progress_stage_two")] == "" and original[header.index("ego_progress_stage_one")]
    aggregates = json.loads((scored / "scores.json").read_text())["aggregates"]
    assert float(rows[-1][-1]) == aggregates["extended_pdm_score_combined"]
    assert float(rows[-3][-1]) == pytest.approx(aggregates["extended_pdm_score_stage_one"])


def test_predictions_missing_a_stage_two_token_fail_naming_it(
    converted: Path, scored: Path, mapping: list, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    dropped = mapping[1].pairs[2][0]
    predictions = [
        predict_constant_velocity(s)
        for s in read_samples(converted, fields=())
        if s["meta"]["extras"]["navsim"]["scene_token"] != dropped
    ]
    path = write_predictions(tmp_path / "predictions.parquet", predictions)
    args = ["score", "--metric", "epdms@navsim-2.2", "--predictions", str(path), "--data", str(converted)]
    references = ["--reference-cache", str(scored.parent / "navhard_references")]
    assert cli_main([*args, "--out", str(tmp_path / "scores"), *references]) == 2
    error = capsys.readouterr().err.strip()
    assert "\n" not in error and f"stage-2 token {dropped}" in error and "no prediction" in error
    assert not (tmp_path / "scores" / "scores.json").exists()


def test_two_stage_false_scores_every_frame_as_one_stage(converted: Path, scored: Path, tmp_path: Path) -> None:
    args = ["score", "--metric", "epdms@navsim-2.2", "--planner", "constant-velocity", "--data", str(converted)]
    references = ["--reference-cache", str(scored.parent / "navhard_references")]
    assert cli_main([*args, "--out", str(tmp_path), *references, "--option", "two_stage=false"]) == 0
    aggregates = json.loads((tmp_path / "scores.json").read_text())["aggregates"]
    assert "extended_pdm_score_combined" not in aggregates and aggregates["frames"] == 24
    assert (tmp_path / "navsim_epdms.csv").exists() and not (tmp_path / CSV_NAME).exists()


def test_a_pedestrian_logs_synthetic_scenes_hold_its_pedestrians(tmp_path: Path) -> None:
    """Log 3 is a pedestrian log (``synth.is_pedestrian_log``): its synthetic scenes hold the row across the lane
    that its stage-1 frames hold, and no lead vehicle (before, they looked for the log's agents in vain)."""
    hard.generate(tmp_path, count=4, seed=1)
    assert synth.log_specs(4, seed=1)[3].brake_at is not None
    split = yaml.safe_load((tmp_path / "train_test_split" / f"{hard.SPLIT}.yaml").read_text())
    now = split["reactive_all_mapping"][3][2][0][0]  # the log's first offset, the scene now
    scene = navsim_synthetic.load_scene(tmp_path / hard.SPLIT / "synthetic_scene_pickles" / f"{now}.pkl")
    classes = list(navsim_synthetic.tracked_objects(scene["extended_detections_tracks"][0], "test").classes)
    assert classes.count(BoxClass.PEDESTRIAN) == len(pedestrians_ahead.ROW) + 1  # and the walker
    assert classes.count(BoxClass.VEHICLE) == 1  # the parked car
