"""PDMS v1.1 on synthetic NAVSIM data converted by the adapter: scenes from samples (route correction,
centreline), the scorer's input, and end to end through ``lead-s2r score`` and the validation callback."""

import csv
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from lead_s2r.cli import main as cli_main
from lead_s2r.convert import convert
from lead_s2r.predictions import Prediction, PredictionError
from lead_s2r.schema import SchemaError
from lead_s2r.scoring.baselines import predict_constant_velocity, predict_human
from lead_s2r.scoring.navsim import EPDMSScorer, PDMSScorer, proposals
from lead_s2r.scoring.navsim.pdms_scorer import NAVSIM_COLUMNS
from lead_s2r.scoring.navsim.proposals import ReferenceCache, proposal_of
from lead_s2r.scoring.pdm import score_proposals
from lead_s2r.scoring.pdm.pdm_closed import plan_reference
from lead_s2r.scoring.pdm.route import LaneGraph, correct_route
from lead_s2r.scoring.pdm.sample import scene_from_sample
from lead_s2r.scoring.pdm.scene import PDMScene
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim as synth
from lead_s2r.synthetic import navsim_map as synth_map
from lead_s2r.training.scoring_callback import ScoringCallback
from lead_s2r_adapters.navsim import NavsimAdapter

BASE = synth.LOGS[0]
#: a straight drive that eases off (the lead car pulls away), and a left turn with the ego already in the arc
CRUISE = replace(BASE, name="2021.05.12.22.00.38_veh-35_00001_00002", accel=-0.4)
MID_TURN = replace(
    BASE,
    name="2021.06.07.18.53.26_veh-26_00003_00004",
    lanes=(1012, 2021, 1032),
    start=100.6,  # s = 109.6 m at the first scene's current frame: mid-arc, heading ~45 degrees
    speed=6.0,
    accel=0.0,
    command=(1, 0, 0, 0),
    roadblocks=("101", "202", "103"),
)


def convert_cruise_and_turn(raw: Path, out: Path) -> Path:
    """A cruise and a mid-turn NAVSIM log (14 samples) written to ``raw`` and converted with maps into ``out``."""
    synth_map.write_map(raw / "maps")
    rng = np.random.default_rng(0)
    logs = {spec.name: synth.write_log(raw, spec, rng) for spec in (CRUISE, MID_TURN)}
    synth.write_scene_filter(raw / "scene_filters" / "navmini.yaml", logs)
    adapter = NavsimAdapter(scene_filter=str(raw / "scene_filters" / "navmini.yaml"), maps=str(raw / "maps"))
    assert convert(adapter, raw, out).ok
    return out


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return convert_cruise_and_turn(tmp_path_factory.mktemp("pdms_raw"), tmp_path_factory.mktemp("pdms_out"))


@pytest.fixture(scope="module")
def first(converted: Path) -> dict[str, dict]:
    """The first scene of each log, by log name."""
    firsts: dict[str, dict] = {}
    for sample in read_samples(converted):
        firsts.setdefault(sample["meta"]["extras"]["navsim"]["log_name"], sample)
    return firsts


def test_scene_follows_the_corrected_route_through_the_turn(first: dict) -> None:
    scene = scene_from_sample(first[MID_TURN.name])
    assert set(scene.route_lane_ids.tolist()) == {1011, 1012, 2021, 1031, 1032}
    assert scene.speed_limit_mps == pytest.approx(8.0)  # the start lane is the arc 2021
    # the centreline runs from the arc into lane 1032, heading north at its end
    end = scene.centerline[-1]
    assert end[1] > 50.0 and abs(np.sin(end[2] + np.deg2rad(45.0)) - 1.0) < 0.05
    assert set(scene.light_route_lane_ids.tolist()) == {1011, 1012, 2021, 1031, 1032}  # uncorrected route, for TLC
    assert scene.ego_past.shape == (4, 8) and scene.ego_past[-1, 0] == 0.0
    assert scene.t0_us == first[MID_TURN.name]["meta"]["timestamp_us"]  # NAVSIM's microsecond interpolation times
    assert scene.agent_poses.shape[1] == 11 and scene.agent_valid[: len(first[MID_TURN.name]["boxes"]), 0].all()


def test_route_correction_prepends_the_way_from_an_off_route_start_and_fills_gaps(first: dict) -> None:
    graph = LaneGraph.from_scoring(first[CRUISE.name]["scoring"])
    assert correct_route(graph, [201, 102], np.zeros(3)) == [101, 201, 102]  # ego on 101: backward search
    assert correct_route(graph, [101, 102], np.zeros(3)) == [101, 201, 102]  # gap between 101 and 102
    assert correct_route(graph, [101, 201, 102, 999], np.zeros(3)) == [101, 201, 102]  # 999: not in the map


def test_sample_without_scoring_names_the_key_and_the_fix(first: dict) -> None:
    sample = {k: v for k, v in first[CRUISE.name].items() if k != "scoring"}
    with pytest.raises(SchemaError, match=r"sample '.*', field 'scoring'.*--maps"):
        scene_from_sample(sample)


def test_scorer_input_keeps_regular_grids_and_resamples_others(first: dict) -> None:
    human = predict_human(first[CRUISE.name])
    poses, interval = proposal_of(human)
    assert interval == pytest.approx(0.5) and poses.shape == (8, 3)
    irregular = Prediction(
        "k", "navsim", np.array([0.3, 1.0, 4.5]), np.array([[3, 0], [10, 0], [45, 0.0]]), np.zeros(3)
    )
    poses, interval = proposal_of(irregular)
    assert interval == 0.5 and poses.shape == (8, 3)
    np.testing.assert_allclose(poses[:, 0], 10 * np.arange(0.5, 4.01, 0.5))
    with pytest.raises(PredictionError, match=r"'k'.*yaw"):
        proposal_of(replace(irregular, yaw=np.array([0.0, np.nan, 0.0])))
    with pytest.raises(PredictionError, match="never extrapolated"):
        proposal_of(Prediction("k", "navsim", np.array([0.3, 1.0]), np.zeros((2, 2)), np.zeros(2)))


def test_constant_velocity_is_a_straight_line_at_the_current_speed(first: dict) -> None:
    sample = first[CRUISE.name]
    prediction = predict_constant_velocity(sample)
    speed = np.hypot(*sample["meta"]["ego"]["velocity"])
    np.testing.assert_allclose(prediction.xy[:, 0], speed * 0.5 * np.arange(1, 9), rtol=1e-6)
    assert not prediction.xy[:, 1].any() and not prediction.yaw.any()


def test_score_cli_scores_a_model_free_planner(converted: Path, tmp_path: Path) -> None:
    args = ["score", "--metric", "ade", "--planner", "human", "--data", str(converted), "--out", str(tmp_path)]
    assert cli_main(args) == 0
    aggregates = json.loads((tmp_path / "scores.json").read_text())["aggregates"]
    assert aggregates["ade"] == pytest.approx(0.0, abs=1e-5) and aggregates["frames"] == 14
    assert (tmp_path / "predictions-human.parquet").is_file()


# --------------------------------------------------------------------------- scored end to end


def score_one(sample: dict, prediction: Prediction) -> dict[str, float]:
    poses, interval = proposal_of(prediction)
    scene = scene_from_sample(sample)
    result = score_proposals(scene, poses[None], interval, plan_reference(scene))
    return {name: float(np.asarray(values)[0]) for name, values in result.items()}


def test_human_scores_near_the_top(first: dict) -> None:
    result = score_one(first[CRUISE.name], predict_human(first[CRUISE.name]))
    assert result["no_at_fault_collisions"] == result["drivable_area_compliance"] == 1.0
    assert result["score"] >= 0.9


def test_constant_velocity_through_a_turn_leaves_the_road(first: dict) -> None:
    result = score_one(first[MID_TURN.name], predict_constant_velocity(first[MID_TURN.name]))
    assert result["drivable_area_compliance"] == 0.0 and result["score"] == 0.0


def test_zero_trajectory_of_an_ego_at_rest_makes_no_progress(first: dict) -> None:
    sample = dict(first[CRUISE.name])
    sample["meta"] = {**sample["meta"], "ego": {**sample["meta"]["ego"], "velocity": [0.0, 0.0]}}
    sample["meta"]["ego"]["acceleration"] = [0.0, 0.0]
    zero = Prediction(sample["__key__"], "navsim", 0.5 * np.arange(1, 9), np.zeros((8, 2)), np.zeros(8))
    result = score_one(sample, zero)
    assert result["ego_progress"] == 0.0 and result["no_at_fault_collisions"] == 1.0
    assert result["ep_normaliser_m"] > 5.0  # PDM-Closed drives off, so the threshold does not excuse standing
    moving = score_one(first[CRUISE.name], replace(zero, key=first[CRUISE.name]["__key__"]))
    # a moving ego told to stop still rolls while it brakes, as NAVSIM's simulation does
    assert moving["no_at_fault_collisions"] == 1.0 and 0.0 < moving["ego_progress"] < 0.5


def test_score_cli_writes_navsim_csv_and_reuses_the_reference_cache(converted: Path, tmp_path: Path) -> None:
    cache = tmp_path / "references"
    args = ["score", "--metric", "pdms@navsim-1.1", "--data", str(converted), "--reference-cache", str(cache)]
    assert cli_main([*args, "--planner", "human", "--out", str(tmp_path / "human")]) == 0
    keys = [sample["__key__"] for sample in read_samples(converted, fields=())]
    assert sorted(path.stem for path in cache.glob("*.npy")) == sorted(keys)
    stamps = {path: path.stat().st_mtime_ns for path in cache.glob("*.npy")}
    assert cli_main([*args, "--planner", "constant-velocity", "--out", str(tmp_path / "cv")]) == 0
    assert {path: path.stat().st_mtime_ns for path in cache.glob("*.npy")} == stamps

    report = json.loads((tmp_path / "human" / "scores.json").read_text())
    aggregates = report["aggregates"]
    assert aggregates["frames"] == aggregates["frames_valid"] == len(keys)
    with open(tmp_path / "human" / "navsim_pdms.csv") as file:
        rows = list(csv.reader(file))
    assert rows[0] == ["", "token", "valid", *NAVSIM_COLUMNS]
    assert NAVSIM_COLUMNS[2:5] == ("ego_progress", "time_to_collision_within_bound", "comfort")  # v1.1's order
    assert rows[-1][1] == "average" and len(rows) == len(keys) + 2
    assert float(rows[-1][-1]) == pytest.approx(aggregates["pdms"])
    assert all(len(row[1]) == 16 for row in rows[1:-1])  # NAVSIM scene tokens, not our keys


def test_pdms_and_epdms_plan_each_reference_once_with_a_shared_cache(
    converted: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    planned: list[str] = []

    def counting(scene: PDMScene) -> np.ndarray:
        planned.append(scene.key)
        return plan_reference(scene)

    monkeypatch.setattr(proposals, "plan_reference", counting)
    samples = list(read_samples(converted, fields=EPDMSScorer.fields))
    predictions = [predict_human(sample) for sample in samples]
    cache = ReferenceCache()
    pdms = PDMSScorer(reference_cache=cache).score(predictions, samples).aggregates
    epdms = EPDMSScorer(reference_cache=cache).score(predictions, samples).aggregates
    assert sorted(planned) == sorted(sample["__key__"] for sample in samples)  # once per sample, not twice
    assert pdms["frames_valid"] == epdms["frames_valid"] == len(samples)
    assert PDMSScorer(reference_cache=cache).config()["reference_cache"] is None  # in memory: no folder to report
    alone = PDMSScorer().score(predictions, samples).aggregates
    assert alone["pdms"] == pdms["pdms"] and len(planned) == 2 * len(samples)  # an unshared scorer plans its own


def test_validation_callback_logs_pdms_for_navsim_only(converted: Path) -> None:
    callback = ScoringCallback(converted, metrics=("ade", "pdms@navsim-1.1"))
    predictions = [predict_human(sample) for sample in read_samples(converted, fields=("future",))]
    metrics = callback.compute(predictions)
    assert 0.0 <= metrics["val/navsim/pdms"] <= 1.0 and "val/navsim/ade" in metrics
    assert metrics["val/navsim/no_at_fault_collisions"] <= 1.0 and "val/navsim/frames_valid" not in metrics  # ints
    scorer = callback.scorers[1]
    assert len(scorer.references.memory) == len(predictions)  # planned once, kept for the next epoch
