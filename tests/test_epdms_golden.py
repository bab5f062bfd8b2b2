"""EPDMS v2.2 against the official golden cases (``tests/data/navsim_epdms_v22_official.json.gz``): every sub-score
before and after the human filter, flags, indices, HC's checks, EC and the final score (EC's RMS values:
``test_extended_comfort.py``)."""

import dataclasses
from typing import Any

import numpy as np
import pytest
from pdm_golden import (
    GOLDEN_V22,
    SHORT,
    ego_frame,
    golden_scene,
    load_golden,
    previous_frame,
    reference_poses,
    simulated_states,
)

from lead_s2r.scoring.pdm import epdms
from lead_s2r.scoring.pdm.comfort import history_comfort_checks
from lead_s2r.scoring.pdm.observation import V2_STEPS, log_observation
from lead_s2r.scoring.pdm.score import EPDMS_COLUMNS, EPDMS_METRIC, score_proposals, score_states_v2

GOLDEN = load_golden(GOLDEN_V22)
CASES = {case["id"]: case for case in GOLDEN["scenes"]}
FLAGS = ("multiple_lanes", "non_drivable_area", "oncoming_traffic", "in_intersection", "on_red_light")
CHECKS = ("lon_accel", "lat_accel", "jerk_magnitude", "lon_jerk", "yaw_accel", "yaw_rate")


def _idx(value: int | None) -> int:
    return -1 if value is None else value


def _flag_string(flags: np.ndarray) -> str:
    return "".join("1" if f else "0" for f in flags)


def _check_row(scores: dict[str, np.ndarray], row: int, official: dict[str, Any], names: tuple[str, ...]) -> None:
    for name in names:
        assert scores[SHORT[name]][row] == official[name], name
    assert scores["progress_m"][row] == pytest.approx(official["progress_m"], abs=2e-6)
    assert scores["collision_time_idx"][row] == _idx(official["collision_time_idx"])
    assert scores["ttc_time_idx"][row] == _idx(official["ttc_time_idx"])
    assert scores["lane_keeping_fail_idx"][row] == _idx(official["diagnostics"]["lane_keeping"]["fail_step_idx"])
    for flag in FLAGS:
        assert _flag_string(scores[flag][row]) == official["flags"][flag], flag


def human_states(case: dict[str, Any]) -> np.ndarray:
    return ego_frame(case).states(np.asarray(case["human_trajectory"]["official"]["simulated_states"]))[None]


@pytest.mark.parametrize("case_id", list(CASES))
def test_official_states_score_as_official_before_the_filter(case_id: str) -> None:
    """Reference and trajectories in one call (EP over [reference, row]); the human alone, as the filter scores it."""
    case = CASES[case_id]
    scene = golden_scene(case)
    observation = log_observation(scene, V2_STEPS, replay=True)
    scores = score_states_v2(scene, simulated_states(case), observation, ep_reference=0)
    reference = case["reference_trajectory"]["official"]
    _check_row(scores, 0, reference, ("NC", "DAC", "DDC", "TLC", "TTC", "LK", "HC"))
    for row, trajectory in enumerate(case["trajectories"], start=1):
        official = trajectory["official"]
        _check_row(scores, row, official, ())
        before = official["before_human_filter"]
        for name in SHORT:
            assert scores[SHORT[name]][row] == pytest.approx(before[name], abs=1e-6), (trajectory["id"], name)
        assert scores["multiplicative_metrics_prod"][row] == before["multiplicative_metrics_prod"]
        assert scores["ep_normaliser_m"][row] == pytest.approx(official["ep_normaliser_m"], abs=2e-6)
    human = case["human_trajectory"]["official"]
    alone = dataclasses.replace(scene, ego_past=None)  # the filter passes no past: HC = 1
    human_scores = score_states_v2(alone, human_states(case), observation, ep_reference=None)
    _check_row(human_scores, 0, human, tuple(SHORT))


@pytest.mark.parametrize("case_id", list(CASES))
def test_history_comfort_checks_as_official(case_id: str) -> None:
    case = CASES[case_id]
    scene = golden_scene(case)
    checks = history_comfort_checks(simulated_states(case), scene.ego_past, scene.vehicle)
    for row, trajectory in enumerate(case["trajectories"], start=1):
        official = trajectory["official"]["history_comfort_checks"]
        assert official["num_history_states"] == 14
        assert dict(zip(CHECKS, checks[row].tolist(), strict=True)) == official["checks_pass"], trajectory["id"]
        assert dict(zip(CHECKS, checks[0].tolist(), strict=True)) == official["reference_checks_pass"]


@pytest.mark.parametrize("case_id", list(CASES))
def test_score_proposals_gives_the_official_epdms(case_id: str) -> None:
    """Poses in, final columns out: simulation, log replay, the human filter, EC from the golden previous frames."""
    case = CASES[case_id]
    scene = golden_scene(case)
    trajectories = case["trajectories"]
    for trajectory in trajectories:  # one call per trajectory: their poses differ in count and interval
        scores = score_proposals(
            scene,
            np.asarray(trajectory["poses"])[None],
            trajectory["interval_s"],
            reference_poses(case),
            metric=EPDMS_METRIC,
            previous=[previous_frame(case, trajectory)],
        )
        official = trajectory["official"]
        assert set(scores) == set(EPDMS_COLUMNS)
        for name, column in SHORT.items():
            assert scores[column][0] == pytest.approx(official[name], abs=1e-6), (trajectory["id"], name)
        expected_ec = np.nan if official["EC"] is None else official["EC"]
        assert scores[epdms.EC][0] == pytest.approx(expected_ec, nan_ok=True), trajectory["id"]
        assert scores["score"][0] == pytest.approx(official["EPDMS"], abs=1e-6), trajectory["id"]


def test_the_filter_acts_where_the_human_fails() -> None:
    """N20: the human hits the car the agent hits; NC and TTC of the agent become 1 and its EPDMS 1."""
    case = CASES["N20_filter_human_collides"]
    trajectory = case["trajectories"][0]
    assert trajectory["official"]["human_filter"]["zero_columns_of_human"] == ["NC", "TTC"]
    scene = golden_scene(case)
    scores = score_proposals(
        scene, np.asarray(trajectory["poses"])[None], 0.5, reference_poses(case), metric=EPDMS_METRIC
    )
    assert scores[epdms.NC][0] == 1.0 and scores[epdms.TTC][0] == 1.0 and scores["collision_time_idx"][0] == 24
    assert scores["score"][0] == 1.0  # EC NaN here: (5 + 5 + 2 + 2) / 14
    scene.is_synthetic = True  # no human trajectory: nothing is filtered
    unfiltered = score_proposals(
        scene, np.asarray(trajectory["poses"])[None], 0.5, reference_poses(case), metric=EPDMS_METRIC
    )
    assert unfiltered[epdms.NC][0] == 0.0 and unfiltered["score"][0] == 0.0


def test_states_come_back_for_two_stage_ec() -> None:
    """``with_states``: the proposals' simulated states, those NAVSIM's aggregation compares for EC."""
    case = CASES["N17_ec_pairs"]
    trajectory = case["trajectories"][0]
    scores = score_proposals(
        golden_scene(case),
        np.asarray(trajectory["poses"])[None],
        0.5,
        reference_poses(case),
        metric=EPDMS_METRIC,
        with_states=True,
    )
    official = ego_frame(case).states(np.asarray(trajectory["official"]["simulated_states"]))
    assert scores["simulated_states"].shape == (1, 41, 11)
    assert np.abs(scores["simulated_states"][0] - official).max() < 2e-6
