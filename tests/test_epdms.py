"""EPDMS aggregation and the v2.2 human penalty filter, by hand and against the official v2.2 golden cases."""

import gzip
import json
import math
from pathlib import Path

import numpy as np
import pytest
from pdm_golden import SHORT

from lead_s2r.scoring.pdm import epdms

GOLDEN = Path(__file__).parent / "data" / "navsim_epdms_v22_official.json.gz"


def ones(n: int = 1) -> dict[str, np.ndarray]:
    return {name: np.ones(n) for name in epdms.FILTERED}


def test_all_sub_scores_one_give_one_with_and_without_ec() -> None:
    # the pre-fix filter bug zeroed such rows; with or without EC a perfect row scores exactly 1
    assert epdms.epdms({**ones(), epdms.EC: np.ones(1)}) == pytest.approx([1.0], abs=0)
    assert epdms.epdms(ones()) == pytest.approx([1.0], abs=0)


def test_ec_nan_drops_its_weight_denominator_14() -> None:
    columns = {**ones(2), epdms.EP: np.array([0.5, 0.5]), epdms.EC: np.array([np.nan, 0.0])}
    # NaN EC: (5*0.5 + 5 + 2 + 2) / 14; EC 0: (2.5 + 9 + 0) / 16
    assert epdms.epdms(columns) == pytest.approx([11.5 / 14, 11.5 / 16], abs=1e-15)
    values, weights = epdms.weighted_metrics(columns)
    assert weights[:, -1].tolist() == [0.0, 2.0] and values[:, -1].tolist() == [0.0, 0.0]


def test_multipliers_scale_the_weighted_average() -> None:
    columns = {
        **ones(3),
        epdms.NC: np.array([0.5, 1.0, 1.0]),
        epdms.DDC: np.array([1.0, 0.5, 0.0]),
        epdms.EC: np.ones(3),
    }
    assert epdms.epdms(columns) == pytest.approx([0.5, 0.5, 0.0], abs=0)


def test_human_crashing_where_the_agent_crashes_sets_nc_one() -> None:
    agent = {**ones(), epdms.NC: np.array([0.0]), epdms.TTC: np.array([0.0]), epdms.EC: np.array([1.0])}
    human = {name: 1.0 for name in epdms.FILTERED} | {epdms.NC: 0.0, epdms.TTC: 0.0}
    filtered = epdms.human_penalty_filter(agent, human)
    assert filtered[epdms.NC].tolist() == [1.0] and filtered[epdms.TTC].tolist() == [1.0]
    assert epdms.epdms(filtered) == pytest.approx([1.0], abs=0)  # the derived score follows the filtered columns
    assert epdms.epdms(agent) == pytest.approx([0.0], abs=0)  # unfiltered input is left alone


def test_filter_ignores_halves_and_synthetic_scenes() -> None:
    agent = {**ones(), epdms.NC: np.array([0.0]), epdms.DDC: np.array([0.5])}
    human = {name: 1.0 for name in epdms.FILTERED} | {epdms.NC: 0.5, epdms.DDC: 0.5}
    assert epdms.human_penalty_filter(agent, human)[epdms.NC].tolist() == [0.0]
    assert epdms.human_penalty_filter(agent, human)[epdms.DDC].tolist() == [0.5]
    assert epdms.human_penalty_filter(agent, None)[epdms.NC].tolist() == [0.0]
    with pytest.raises(KeyError, match="drivable_area_compliance"):
        epdms.human_penalty_filter(agent, {epdms.NC: 0.0})


def golden_trajectories() -> list[tuple[str, dict, dict]]:
    data = json.loads(gzip.decompress(GOLDEN.read_bytes()))
    return [
        (trajectory["id"], trajectory["official"], scene["human_trajectory"]["official"])
        for scene in data["scenes"]
        for trajectory in scene["trajectories"]
    ]


def columns_of(record: dict) -> dict[str, np.ndarray]:
    return {SHORT[short]: np.array([float(record[short])]) for short in SHORT}


@pytest.mark.parametrize(
    ("case", "official", "human"), golden_trajectories(), ids=lambda v: v if isinstance(v, str) else ""
)
def test_golden_filter_and_final_score(case: str, official: dict, human: dict) -> None:
    before = columns_of(official["before_human_filter"])
    assert epdms.multiplicative_product(before)[0] == official["before_human_filter"]["multiplicative_metrics_prod"]
    # the scorer's own pdm_score column is the pre-filter EPDMS without EC: the /14 branch
    assert epdms.epdms(before)[0] == pytest.approx(official["scorer_pdm_score_column"], abs=1e-12)
    after = epdms.human_penalty_filter(before, {SHORT[k]: v for k, v in human.items() if k in SHORT})
    for short, name in SHORT.items():
        assert after[name][0] == official[short], f"{case}: {short}"
    assert epdms.multiplicative_product(after)[0] == official["multiplicative_metrics_prod"]
    ec = math.nan if official["EC"] is None else official["EC"]
    values, weights = epdms.weighted_metrics({**after, epdms.EC: np.array([ec])})
    assert values[0, :4].tolist() == official["weighted_metrics"][:4]
    assert weights[0].tolist() == [*official["weighted_metrics_array"][:4], 0.0 if math.isnan(ec) else 2.0]
    assert epdms.epdms({**after, epdms.EC: np.array([ec])})[0] == pytest.approx(official["EPDMS"], abs=1e-6)
