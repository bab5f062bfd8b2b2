"""RFS against the official samples, the official zero and grid cases, hand cases A-G and properties."""

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rfs_lists import pad_rater_lists
from test_score_cli import GRID, prediction, scoring_sample, straight

from lead_s2r.predictions import PredictionError
from lead_s2r.schema import SchemaError
from lead_s2r.scoring.rfs import RFSConfig, RFSScorer, pad_raters, rater_feedback_score, speed_scale

# the official unit-test samples (Apache-2.0), copied into tests/data so the suite stands alone
GOLDEN = json.loads((Path(__file__).parent / "data" / "wod_rfs_official_samples.json").read_text())


def shifted(xy: np.ndarray, dx: float, dy: float) -> np.ndarray:
    return xy + np.array([dx, dy])


def score_one(pred: np.ndarray, raters: list[np.ndarray], labels: list[float], speed: float, **config: object):
    """RFS of a single frame with one inference; returns (score, fully_within)."""
    cfg = RFSConfig(**config)
    padded, padded_labels = pad_rater_lists([raters], [labels], cfg)
    result = rater_feedback_score(pred[None, None], np.ones((1, 1)), padded, padded_labels, np.array([speed]), cfg)
    return float(result.score[0]), bool(result.fully_within[0, 0])


@pytest.mark.parametrize(("model", "floor"), list(itertools.product((1, 2, 3), (0, 4))))
def test_official_samples(model: int, floor: int) -> None:
    samples = GOLDEN["samples"]
    config = RFSConfig(frequency=1, length_seconds=5, floor=float(floor))
    raters, labels = pad_rater_lists(
        [[np.array(t) for t in s["rater_specified_trajectories"]] for s in samples],
        [s["rater_feedback_labels"] for s in samples],
        config,
    )
    predictions = np.array([s[f"inference_trajectories_MODEL{model}"] for s in samples])
    speed = np.array([s["speed"] for s in samples])
    result = rater_feedback_score(predictions, np.ones((4, 1)), raters, labels, speed, config)
    np.testing.assert_allclose(result.score, GOLDEN[f"expected_floor{floor}_MODEL{model}"], rtol=0, atol=1e-12)
    assert result.fully_within[:, 0].tolist() == GOLDEN[f"fully_within_MODEL{model}"]


def test_official_zeros() -> None:
    raters = np.zeros((2, 3, 20, 2))
    result = rater_feedback_score(
        np.zeros((2, 2, 20, 2)), np.full((2, 2), 0.5), raters, np.full((2, 3), 10.0), np.zeros(2)
    )
    np.testing.assert_array_equal(result.score, [10.0, 10.0])
    assert result.fully_within.all()


@pytest.mark.parametrize(
    ("multipliers", "decay", "floor"), list(itertools.product(((1, 2), (1, 4)), (0.1, 0.2, 0.3), (0, 0.4)))
)
def test_official_grid(multipliers: tuple[float, float], decay: float, floor: float) -> None:
    config = RFSConfig(frequency=1, length_seconds=5, lat_lng_multipliers=multipliers, decay=decay, floor=floor)
    rater = np.stack([np.arange(1.0, 6.0), np.zeros(5)], axis=-1)
    shifts = np.linspace(-2, 2, 9)
    grids = []
    for speed in (0.0, 1.4, 6.2, 11.0, 22.0):
        scale = speed_scale(np.array(speed), config)
        lat_thr = scale * np.array(config.base_thresholds) * multipliers[0]
        lng_thr = scale * np.array(config.base_thresholds) * multipliers[1]
        preds = np.repeat(rater[None], 81, axis=0)
        for n, (lng, lat) in enumerate(itertools.product(shifts, shifts)):
            preds[n, [2, 4], 0] += lng * lng_thr
            preds[n, [2, 4], 1] += lat * lat_thr
        raters, labels = pad_rater_lists([[rater]] * 81, [[1.0]] * 81, config)
        result = rater_feedback_score(preds[:, None], np.ones((81, 1)), raters, labels, np.full(81, speed), config)
        grids.append(result.score.reshape(9, 9))
    for grid in grids[1:]:
        np.testing.assert_allclose(grid, grids[0], atol=1e-12)
    grid = grids[0]
    np.testing.assert_allclose(grid[2:7, 2:7], 1.0, atol=1e-12)
    np.testing.assert_allclose(grid, grid[::-1], atol=1e-12)
    np.testing.assert_allclose(grid, grid[:, ::-1], atol=1e-12)
    ring = np.maximum(np.abs(shifts)[:, None], np.abs(shifts)[None, :])
    np.testing.assert_allclose(grid[ring == 2], max(floor, decay), atol=1e-12)
    np.testing.assert_allclose(grid[ring == 1.5], max(floor, np.sqrt(decay)), atol=1e-12)


ONE_HZ = {"frequency": 1.0, "length_seconds": 5.0}
RATER = straight(10.0)  # r_k = (10 t_k, 0), label 10, v0 = 10 m/s in the hand cases


def test_hand_case_a_prediction_on_rater() -> None:
    assert score_one(RATER, [RATER], [10], 10.0) == (10.0, True)


def test_hand_case_b_lateral_1_5m() -> None:
    score, within = score_one(shifted(RATER, 0, 1.5), [RATER], [10], 10.0)
    assert score == pytest.approx(6.307833392636335, abs=1e-12) and not within


def test_hand_case_c_lateral_3m_hits_the_floor() -> None:
    assert score_one(shifted(RATER, 0, 3.0), [RATER], [10], 10.0) == (4.0, False)
    raw, _ = score_one(shifted(RATER, 0, 3.0), [RATER], [10], 10.0, floor=0.0)
    assert raw == pytest.approx(0.91, abs=0.01)


def test_hand_case_d_floor_not_applied_inside_a_low_rater() -> None:
    assert score_one(RATER, [RATER, shifted(RATER, 0, 10)], [2, 10], 10.0) == (2.0, True)


def test_hand_case_e_checkpoints_pick_different_raters() -> None:
    rater_a, rater_b = RATER.copy(), RATER.copy()
    rater_a[11, 1] += 5.0
    rater_b[19, 1] += 5.0
    assert score_one(RATER, [rater_a, rater_b], [8, 6], 10.0) == (7.0, False)


def test_hand_case_f_standing_still() -> None:
    assert score_one(np.zeros((20, 2)), [RATER], [10], 0.0) == (4.0, False)


def test_hand_case_g_longitudinal_3m_inside() -> None:
    assert score_one(shifted(RATER, 3.0, 0), [RATER], [10], 10.0) == (10.0, True)


def test_speed_scale_table() -> None:
    speeds = np.array([0.0, 1.4, 6.2, 10.0, 11.0, 22.0])
    np.testing.assert_allclose(speed_scale(speeds), [0.5, 0.5, 0.75, 0.5 + 0.5 * 8.6 / 9.6, 1.0, 1.0], atol=1e-15)


def test_padding_and_truncation() -> None:
    config = RFSConfig(frequency=1, length_seconds=5)
    long = np.arange(14.0).reshape(7, 2)
    short = np.array([[1.0, 2.0], [3.0, 4.0]])
    raters, labels = pad_rater_lists([[long, short]], [[7, 5]], config)
    np.testing.assert_array_equal(raters[0, 0], long[:5])
    np.testing.assert_array_equal(raters[0, 1], [[1, 2], [3, 4], [3, 4], [3, 4], [3, 4]])
    np.testing.assert_array_equal(raters[0, 2], raters[0, 1])
    np.testing.assert_array_equal(labels, [[7, 5, 5]])
    raters, labels = pad_rater_lists([[short] * 4], [[1, 2, 3, 4]], config)
    np.testing.assert_array_equal(labels, [[1, 2, 3]])
    with pytest.raises(ValueError, match="at least one rater"):
        pad_raters(np.zeros((1, 1, 5, 2)), np.array([[0]]), np.array([1]), np.ones((1, 1)), config)


def test_stationary_rater_and_zero_steps_keep_the_previous_direction() -> None:
    stationary = np.zeros((5, 2))
    # direction (1, 0) for a rater that never moves: 1.9 m along x is inside lng_thr 2.0 at 3 s, 3.6 at 5 s
    assert score_one(np.full((5, 2), [1.9, 0.0]), [stationary], [10], 0.0, **ONE_HZ)[1]
    assert not score_one(np.full((5, 2), [0.0, 0.6]), [stationary], [10], 0.0, **ONE_HZ)[1]
    # a rater that moves along +y then stops: the direction stays +y, so a 1.9 m offset along y is longitudinal
    stop = np.array([[0, 1.0], [0, 2.0], [0, 2.0], [0, 2.0], [0, 2.0]])
    assert score_one(shifted(stop, 0, 1.9), [stop], [10], 0.0, **ONE_HZ)[1]
    assert not score_one(shifted(stop, 0.6, 0), [stop], [10], 0.0, **ONE_HZ)[1]


def test_probability_weighted_sum() -> None:
    raters, labels = pad_rater_lists([[RATER]], [[10]])
    preds = np.stack([RATER, shifted(RATER, 0, 3.0)])[None]
    result = rater_feedback_score(preds, np.array([[0.25, 0.75]]), raters, labels, np.array([10.0]))
    np.testing.assert_allclose(result.per_inference, [[10.0, 4.0]])
    assert result.score[0] == pytest.approx(0.25 * 10 + 0.75 * 4, abs=1e-12)


def test_bad_shapes() -> None:
    raters, labels = pad_rater_lists([[RATER]], [[10]])
    with pytest.raises(ValueError, match="disagree"):
        rater_feedback_score(np.zeros((1, 1, 10, 2)), np.ones((1, 1)), raters, labels, np.zeros(1))


coordinate = st.floats(-60, 60).map(lambda v: round(v, 3))  # real raters: cm resolution, no subnormal steps
trajectory = st.integers(1, 24).flatmap(
    lambda n: st.lists(st.tuples(coordinate, coordinate), min_size=n, max_size=n).map(np.array)
)
frame = st.lists(st.tuples(trajectory, st.integers(0, 10)), min_size=1, max_size=4)


@settings(max_examples=60, deadline=None)
@given(frame, st.floats(0, 30), trajectory)
def test_mirror_invariance(raters: list[tuple[np.ndarray, int]], speed: float, pred: np.ndarray) -> None:
    pred = np.resize(pred, (20, 2))
    trajectories, labels = [r for r, _ in raters], [float(label) for _, label in raters]
    mirror = np.array([1.0, -1.0])
    original = score_one(pred, trajectories, labels, speed)
    mirrored = score_one(pred * mirror, [r * mirror for r in trajectories], labels, speed)
    assert mirrored[1] == original[1]
    assert mirrored[0] == pytest.approx(original[0], abs=1e-12)
    assert 0.0 <= original[0] <= 10.0


@settings(max_examples=60, deadline=None)
@given(frame, st.floats(0, 30))
def test_prediction_on_the_best_rater_scores_its_label(raters: list[tuple[np.ndarray, int]], speed: float) -> None:
    trajectories, labels = [r for r, _ in raters], [float(label) for _, label in raters]
    padded, _ = pad_rater_lists([trajectories], [labels])
    best = int(np.argmax(labels[:3]))
    assert score_one(padded[0, best], trajectories, labels, speed) == (max(labels[:3]), True)


def test_scorer_resamples_other_grids_and_never_extrapolates() -> None:
    sample = scoring_sample("seg_a", raters=[(RATER, 9.0)])
    t2 = np.arange(1, 11) * 0.5  # 2 Hz x 10, ends at 5 s
    result = RFSScorer().score([prediction("seg_a", straight(10, t2), t=t2)], [sample])
    assert result.table["rfs"].to_pylist() == [pytest.approx(9.0, abs=1e-12)]
    lead_grid = np.arange(10) * 0.5 + 0.25  # LEAD's [::2] grid ends at 4.75 s
    with pytest.raises(PredictionError, match=r"'seg_a': horizon 4\.75 s ends before the scored 5 s"):
        RFSScorer().score([prediction("seg_a", straight(10, lead_grid), t=lead_grid)], [sample])


def test_scorer_multi_inference_and_sub_scores() -> None:
    sample = scoring_sample("seg_a", raters=[(RATER, 10.0)])
    predictions = [
        prediction("seg_a", RATER, probability=0.6, inference=0),
        prediction("seg_a", shifted(RATER, 0, 3.0), probability=0.4, inference=1),
    ]
    table = RFSScorer(floor=0.0).score(predictions, [sample]).table.to_pydict()
    at_3s = 0.6 * 10 + 0.4 * 10 * 0.1 ** (3.0 / speed_scale(np.array(10.0)) - 1)
    assert table["rfs_3s"] == [pytest.approx(at_3s, abs=1e-12)]
    assert table["fully_within"] == [True]  # of the most probable inference
    assert GRID[11] == 3.0 and GRID[19] == 5.0


def test_malformed_raters_name_the_sample() -> None:
    sample = scoring_sample("seg_a", raters=[(RATER, 9.0)])
    sample["raters"]["lengths"] = np.array([25], np.int32)
    with pytest.raises(SchemaError, match=r"'seg_a', field 'raters': lengths \[25\] outside 1\.\.20"):
        RFSScorer().score([prediction("seg_a", RATER)], [sample])
