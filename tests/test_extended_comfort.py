"""EC's pairing (overlap offset 5, 36 states) and RMS bounds, by hand and on the official golden simulated states."""

import gzip
import json
from pathlib import Path

import numpy as np
import pytest

from lead_s2r.scoring.pdm import extended_comfort as ec
from lead_s2r.scoring.pdm.comfort import extended_comfort_features
from lead_s2r.scoring.pdm.state import STATE_SIZE

GOLDEN = Path(__file__).parent / "data" / "navsim_epdms_v22_official.json.gz"


def features(value: float = 0.0, n: int = 36, **changes: np.ndarray) -> dict[str, np.ndarray]:
    return {name: np.full(n, value) for name in ec.THRESHOLDS} | changes


def test_overlap_pairs_current_head_with_previous_tail() -> None:
    steps = np.arange(41, dtype=np.float64)[:, None] * np.ones(STATE_SIZE)
    now, before, time = ec.overlap(steps, steps + 100, 0.5)
    assert now.shape == before.shape == (36, STATE_SIZE)
    assert now[0, 0] == 0 and now[-1, 0] == 35  # current[:-5]
    assert before[0, 0] == 105 and before[-1, 0] == 140  # previous[5:]
    assert time == pytest.approx(np.arange(36) * 0.1)
    assert ec.overlap(steps, steps, 0.46)[0].shape == (36, STATE_SIZE)  # round(4.6) = 5, as the official code


@pytest.mark.parametrize("interval", [0.0, -0.5, 0.55, 1.0])
def test_overlap_rejects_frames_that_do_not_pair(interval: float) -> None:
    states = np.zeros((41, STATE_SIZE))
    with pytest.raises(ValueError, match="apart"):
        ec.overlap(states, states, interval)


def test_rms_bounds_are_inclusive() -> None:
    # a constant difference of exactly the bound passes; anything above fails
    assert ec.is_extended_comfortable(features(0.7, acceleration=np.full(36, 1.4)), features(0.7))
    assert not ec.is_extended_comfortable(features(0.0, acceleration=np.full(36, 0.7001)), features(0.0))
    assert ec.is_extended_comfortable(features(yaw_rate=np.full(36, -0.1)), features())
    assert not ec.is_extended_comfortable(features(yaw_accel=np.full(36, 0.1001)), features())


def test_rms_of_alternating_differences() -> None:
    jerk = np.tile([0.3, -0.4], 18)
    rms = ec.rms_differences(features(jerk=jerk), features())
    assert rms["jerk"] == pytest.approx(np.sqrt((0.09 + 0.16) / 2))  # 0.354 <= 0.5
    assert rms["acceleration"] == 0.0
    assert ec.is_extended_comfortable(features(jerk=jerk), features())
    assert not ec.is_extended_comfortable(features(jerk=2 * jerk), features())  # 0.707 > 0.5
    with pytest.raises(KeyError, match="yaw_accel"):
        ec.rms_differences({"acceleration": jerk, "jerk": jerk, "yaw_rate": jerk}, features())


def golden_pairs() -> list[tuple[str, dict, dict]]:
    data = json.loads(gzip.decompress(GOLDEN.read_bytes()))
    return [
        (t["id"], t["official"], t["previous_frame"]["official"])
        for scene in data["scenes"]
        for t in scene["trajectories"]
        if t.get("previous_frame")
    ]


@pytest.mark.parametrize(
    ("case", "official", "previous"), golden_pairs(), ids=lambda v: v if isinstance(v, str) else ""
)
def test_golden_pairs(case: str, official: dict, previous: dict) -> None:
    now, before, time = ec.overlap(np.array(official["simulated_states"]), np.array(previous["simulated_states"]), 0.5)
    assert len(now) == official["ec_overlap_states"]
    rms = ec.rms_differences(extended_comfort_features(now, time), extended_comfort_features(before, time))
    # the golden states are rounded to 1e-6; second derivatives over 0.1 s amplify that ~100-fold: then the verdict
    assert rms == pytest.approx(official["ec_rms"], abs=2e-4), case
    value = ec.two_frame_extended_comfort(
        np.array(official["simulated_states"]), np.array(previous["simulated_states"]), 0.5, extended_comfort_features
    )
    assert value == official["EC"], case
