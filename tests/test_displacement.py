"""ADE/FDE against the logged future, ADE@3s/5s against the best rater, and the time-grid resampling under them."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_score_cli import GRID, prediction, scoring_sample, straight

from lead_s2r.predictions import PredictionError, on_grid, regular_grid
from lead_s2r.scoring.displacement import DisplacementScorer, best_rater_ade, future_errors

NAVSIM_T = np.arange(1, 9) * 0.5  # 2 Hz x 4 s


def future_of(t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    return np.c_[t, xy, np.zeros(len(t))].astype(np.float32)


def test_constant_offset_gives_equal_ade_and_fde() -> None:
    future = future_of(NAVSIM_T, straight(8, NAVSIM_T))
    errors = future_errors([prediction("k", straight(8, NAVSIM_T) + np.array([3.0, 4.0]), t=NAVSIM_T)], future)
    assert errors == pytest.approx({"ade": 5.0, "fde": 5.0, "min_ade": 5.0, "min_fde": 5.0, "horizon_s": 4.0})


def test_shorter_prediction_is_compared_up_to_its_horizon() -> None:
    future = future_of(GRID, straight(10))
    t = GRID[:12]  # the prediction stops at 3 s; its error grows as t metres to the left
    errors = future_errors([prediction("k", straight(10, t) + np.c_[0 * t, t], t=t)], future)
    assert errors["horizon_s"] == 3.0
    assert errors["ade"] == pytest.approx(t.mean(), abs=1e-6) and errors["fde"] == pytest.approx(3.0, abs=1e-6)
    late = future_errors([prediction("k", straight(10, t), t=t)], future_of(GRID[14:], straight(10, GRID[14:])))
    assert np.isnan(late["ade"]) and np.isnan(late["horizon_s"])


def test_top_inference_and_min_over_inferences() -> None:
    future = future_of(GRID, straight(10))
    frame = [
        prediction("k", straight(10), probability=0.3, inference=0),
        prediction("k", straight(10, lateral=2.0), probability=0.7, inference=1),
    ]
    errors = future_errors(frame, future)
    assert (errors["ade"], errors["fde"], errors["min_ade"], errors["min_fde"]) == pytest.approx((2, 2, 0, 0))


def test_coarser_prediction_is_interpolated_from_the_origin() -> None:
    t2 = np.arange(1, 11) * 0.5
    curve = np.c_[5 * t2, t2**2]  # a left turn sampled at 2 Hz
    xy, probabilities = on_grid([[prediction("k", curve, t=t2)]], GRID)
    expected_y = np.interp(GRID, np.r_[0.0, t2], np.r_[0.0, t2**2])
    np.testing.assert_allclose(xy[0, 0, :, 1], expected_y, atol=1e-6)
    np.testing.assert_array_equal(xy[0, 0, 1::2], curve.astype(np.float32))  # on-grid points pass unchanged
    assert probabilities.tolist() == [[1.0]]
    with pytest.raises(PredictionError, match=r"'k': horizon 4\.75 s"):
        on_grid([[prediction("k", curve[:-1] * 0, t=t2[:-1] + 0.25)]], GRID)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(0.05, 1.0), min_size=2, max_size=30), st.floats(-20, 20), st.floats(-5, 5))
def test_resampling_is_exact_for_constant_velocity(steps: list[float], vx: float, vy: float) -> None:
    t = np.cumsum(np.round(steps, 2)).astype(np.float32)
    target = np.linspace(0.01, float(t[-1]), 17)
    xy, _ = on_grid([[prediction("k", np.c_[vx * t, vy * t], t=t)]], target)
    np.testing.assert_allclose(xy[0, 0], np.c_[vx * target, vy * target], atol=1e-3)


def test_best_rater_ade_at_3_and_5_seconds() -> None:
    best = straight(10)
    pred = best + np.where(GRID[:, None] <= 3.0, [0.0, 1.0], [0.0, 3.0])
    raters = np.stack([straight(10, lateral=-1.0), best])[None]
    ade = best_rater_ade(pred[None, None], np.ones((1, 1)), raters, np.array([[6.0, 9.0]]), GRID)
    np.testing.assert_allclose(ade, [[1.0, (12 * 1 + 8 * 3) / 20]], atol=1e-12)


def test_scorer_rows_and_per_dataset_aggregates() -> None:
    short_rater = straight(10)[:11]  # padded with its last point (2.75 s) like RFS does
    samples = [
        scoring_sample("wod_0", raters=[(short_rater, 7.0)], future=future_of(GRID, straight(10))),
        scoring_sample("wod_1"),
        scoring_sample("nav_0", dataset="navsim", future=future_of(NAVSIM_T, straight(8, NAVSIM_T))),
    ]
    predictions = [
        prediction("wod_0", straight(10)),
        prediction("wod_1", straight(10)),
        prediction("nav_0", straight(8, NAVSIM_T, lateral=0.5), t=NAVSIM_T, dataset="navsim"),
    ]
    result = DisplacementScorer().score(predictions, samples)
    rows = result.table.to_pydict()
    padded_error = np.abs(10 * GRID - 10 * np.minimum(GRID, 2.75))
    assert rows["ade_3s"][0] == pytest.approx(padded_error[:12].mean(), abs=1e-9)
    assert rows["ade_5s"][0] == pytest.approx(padded_error.mean(), abs=1e-9)
    assert rows["ade"][0] == pytest.approx(0.0, abs=1e-9) and np.isnan(rows["ade"][1])
    aggregates = result.aggregates
    assert aggregates["per_dataset"]["navsim"]["ade"] == pytest.approx(0.5, abs=1e-6)
    assert aggregates["per_dataset"]["wod_e2e"]["frames_with_future"] == 1
    assert aggregates["frames"] == 3 and aggregates["frames_rated"] == 1
    assert aggregates["ade"] == pytest.approx(0.25, abs=1e-6)


def test_regular_grid() -> None:
    np.testing.assert_allclose(regular_grid(4, 5), GRID)
    assert len(regular_grid(2, 4)) == 8 and regular_grid(2, 4)[-1] == 4.0
