"""Two-stage (pseudo closed-loop) aggregation on one hand-worked navhard group."""

import dataclasses
import math

import numpy as np
import pytest

from lead_s2r.formats.navsim_two_stage import TwoStageGroup, parse_mapping
from lead_s2r.scoring.pdm import epdms, two_stage
from lead_s2r.scoring.pdm.state import STATE_SIZE, StateIndex


def accel_only(states: np.ndarray, time: np.ndarray) -> dict[str, np.ndarray]:
    """Test extractor: EC then compares the raw longitudinal accelerations (bound 0.7) and nothing else."""
    zeros = np.zeros(len(time))
    return {"acceleration": states[:, StateIndex.ACCELERATION_X], "jerk": zeros, "yaw_rate": zeros, "yaw_accel": zeros}


def row(token: str, t: float, start: tuple, end: tuple, accel: float = 0.0, **columns: float) -> two_stage.TokenRow:
    states = np.zeros((41, STATE_SIZE))
    states[:, StateIndex.ACCELERATION_X] = accel
    values = {name: 1.0 for name in epdms.FILTERED} | {getattr(epdms, k): v for k, v in columns.items()}
    return two_stage.TokenRow(token, values, t, np.array(start, float), np.array(end, float), states)


GROUP = TwoStageGroup("orig", "prev", (("now1", "prev1"), ("now2", "prev2")))


def rows() -> list[two_stage.TokenRow]:
    return [
        row("orig", 10.0, (0, 0), (10.0, 0.0)),
        row("prev", 9.5, (-5, 0), (5.0, 0.0), EP=0.6),
        # "now" variants start 0 m and 0.3 m from orig's planned endpoint: weights 1 and exp(-0.45), normalised
        row("now1", 14.0, (10.0, 0.0), (20, 0)),
        row("now2", 14.0, (10.3, 0.0), (20, 0), EP=0.2),
        # "previous" variants start 4 m and 3 m from prev's endpoint: raw weights ~1e-35 and ~1e-20 -> equal weights
        row("prev1", 13.5, (9.0, 0.0), (20, 0), NC=0.0),
        row("prev2", 13.5, (8.0, 0.0), (20, 0), accel=1.0),  # its pair with now2 differs by 1.0 m/s^2: EC 0
    ]


def test_weights_gaussian_and_equal_fallback() -> None:
    w = two_stage.pseudo_closed_loop_weights(np.array([10.0, 0.0]), np.array([[10.0, 0.0], [10.3, 0.0]]))
    assert w == pytest.approx([1 / (1 + math.exp(-0.45)), math.exp(-0.45) / (1 + math.exp(-0.45))], rel=1e-12)
    far = two_stage.pseudo_closed_loop_weights(np.array([5.0, 0.0]), np.array([[9.0, 0.0], [8.0, 0.0], [5.0, 2.0]]))
    assert far.tolist() == [1 / 3, 1 / 3, 1 / 3]  # exp(-2^2 / 0.2) = 2e-9 still sums to "about zero"
    near = two_stage.pseudo_closed_loop_weights(np.array([5.0, 0.0]), np.array([[5.0, 1.5], [5.0, 2.0]]))
    assert near == pytest.approx([1 / (1 + math.exp(-8.75)), 1 - 1 / (1 + math.exp(-8.75))])  # 1.5 m still counts


def test_hand_worked_group() -> None:
    result = two_stage.two_stage_aggregate(rows(), [GROUP], accel_only)
    per = result.per_token
    w1 = 1 / (1 + math.exp(-0.45))
    assert per["now1"]["weight"] == pytest.approx(w1) and per["now2"]["weight"] == pytest.approx(1 - w1)
    assert per["prev1"]["weight"] == per["prev2"]["weight"] == 0.5
    assert per["orig"]["weight"] == per["prev"]["weight"] == 1.0
    # EC: both frames of a pair get the pair's value
    assert [per[t][epdms.EC] for t in ("orig", "prev", "now1", "prev1", "now2", "prev2")] == [1, 1, 1, 1, 0, 0]
    scores = {t: per[t]["score"] for t in per}
    assert scores == pytest.approx(
        {"orig": 1.0, "prev": 14 / 16, "now1": 1.0, "prev1": 0.0, "now2": 10 / 16, "prev2": 14 / 16}
    )
    now_side = w1 * 1.0 + (1 - w1) * 10 / 16
    prev_side = 0.5 * 0.0 + 0.5 * 14 / 16
    assert result.stage_one["score"] == pytest.approx((1.0 + 14 / 16) / 2)
    assert result.stage_two["score"] == pytest.approx((now_side + prev_side) / 2)
    assert result.combined["score"] == pytest.approx((1.0 * now_side + 14 / 16 * prev_side) / 2)
    # sub-scores go through the same column-wise products: NC is 1 everywhere except prev1
    assert result.combined[epdms.NC] == pytest.approx((1.0 + 0.5) / 2)
    assert result.stage_two[epdms.EC] == pytest.approx((w1 + 0.5) / 2)


def test_missing_stage_two_token_is_an_error_naming_it() -> None:
    with pytest.raises(KeyError, match="now2"):
        two_stage.two_stage_aggregate([r for r in rows() if r.token != "now2"], [GROUP], accel_only)
    with pytest.raises(KeyError, match="stray"):
        two_stage.two_stage_aggregate([*rows(), row("stray", 0.0, (0, 0), (0, 0))], [GROUP], accel_only)
    lacking = [dataclasses.replace(r, columns={epdms.NC: 1.0}) if r.token == "prev1" else r for r in rows()]
    with pytest.raises(KeyError, match="prev1 has no column drivable_area_compliance"):
        two_stage.two_stage_aggregate(lacking, [GROUP], accel_only)


def test_pair_frames_must_be_half_a_second_apart() -> None:
    shifted = [row("prev", 9.0, (-5, 0), (5.0, 0.0)) if r.token == "prev" else r for r in rows()]
    with pytest.raises(ValueError, match=r"\(orig, prev\)"):
        two_stage.two_stage_aggregate(shifted, [GROUP], accel_only)


def test_parse_mapping_and_csv_layout() -> None:
    groups = parse_mapping([["orig", "prev", [["now1", "prev1"], ["now2", "prev2"]]]])
    assert groups == [GROUP]
    with pytest.raises(ValueError, match="entry 0"):
        parse_mapping([["orig", "prev"]])
    csv = two_stage.navsim_csv_rows(two_stage.two_stage_aggregate(rows(), groups, accel_only))
    assert [r["token"] for r in csv[-3:]] == list(two_stage.SUMMARY_TOKENS)
    orig = next(r for r in csv if r["token"] == "orig")
    assert orig["ego_progress_stage_one"] == 1.0 and math.isnan(orig["ego_progress_stage_two"])
    assert csv[-1]["score"] == pytest.approx(
        two_stage.two_stage_aggregate(rows(), groups, accel_only).combined["score"]
    )
    assert not math.isnan(csv[-1]["lane_keeping_stage_one"]) and not math.isnan(csv[-1]["lane_keeping_stage_two"])
