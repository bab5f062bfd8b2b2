"""EPDMS v2.2 on synthetic NAVSIM data converted by the adapter: EC pairing of adjacent frames, and end to end
through ``lead-s2r score`` (NAVSIM v2's one-stage CSV) and the validation callback."""

import csv
import json
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from lead_s2r.cli import main as cli_main
from lead_s2r.convert import convert
from lead_s2r.scoring.baselines import predict_human
from lead_s2r.scoring.navsim import epdms_scorer
from lead_s2r.scoring.pdm import epdms
from lead_s2r.scoring.pdm.sample import scene_from_sample
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim as synth
from lead_s2r.synthetic import navsim_map as synth_map
from lead_s2r.training.scoring_callback import ScoringCallback
from lead_s2r_adapters.navsim import NavsimAdapter

CRUISE = replace(synth.LOGS[0], name="2021.05.12.22.00.38_veh-35_00001_00002", accel=-0.4)


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> Path:
    raw = tmp_path_factory.mktemp("epdms_raw")
    synth_map.write_map(raw / "maps")
    logs = {CRUISE.name: synth.write_log(raw, CRUISE, np.random.default_rng(0))}
    synth.write_scene_filter(raw / "scene_filters" / "navmini.yaml", logs)
    out = tmp_path_factory.mktemp("epdms_out")
    adapter = NavsimAdapter(scene_filter=str(raw / "scene_filters" / "navmini.yaml"), maps=str(raw / "maps"))
    assert convert(adapter, raw, out).ok
    return out


def stub(log: str, time_s: float, valid: bool = True, synthetic: bool = False) -> SimpleNamespace:
    """What :func:`adjacent_frames` reads of a frame: its log, time and scene (None: invalid)."""
    return SimpleNamespace(log=log, time_s=time_s, scene=SimpleNamespace(is_synthetic=synthetic) if valid else None)


def test_adjacent_frames_pair_consecutive_originals_of_a_log_within_0p55_s() -> None:
    frames = [
        stub("a", 10.0),
        stub("a", 9.5),  # out of order in the data: sorted by time
        stub("a", 10.5, synthetic=True),  # synthetic frames never pair
        stub("a", 11.0),  # 1.0 s after 10.0: too far
        stub("b", 10.55),  # another log
        stub("a", 11.3, valid=False),  # invalid rows take no part
        stub("a", 11.5),
    ]
    assert epdms_scorer.adjacent_frames(frames) == {0: 1, 6: 3}


def test_score_cli_writes_the_one_stage_csv(converted: Path, tmp_path: Path) -> None:
    args = ["score", "--metric", "epdms@navsim-2.2", "--planner", "human", "--data", str(converted)]
    assert cli_main([*args, "--out", str(tmp_path)]) == 0
    keys = [sample["__key__"] for sample in read_samples(converted, fields=())]
    aggregates = json.loads((tmp_path / "scores.json").read_text())["aggregates"]
    assert aggregates["frames"] == aggregates["frames_valid"] == len(keys)
    with open(tmp_path / epdms_scorer.CSV_NAME) as file:
        rows = list(csv.reader(file))
    assert rows[0] == ["", "token", "valid", *epdms_scorer.NAVSIM_COLUMNS]
    assert epdms_scorer.NAVSIM_COLUMNS[-2:] == ("two_frame_extended_comfort", "score")
    assert rows[-1][1] == "average_all_frames" and len(rows) == len(keys) + 2
    assert float(rows[-1][-1]) == pytest.approx(aggregates["epdms"])
    ec = [row[-2] for row in rows[1:-1]]
    assert aggregates["frames_with_ec"] == sum(value != "" for value in ec) > 0  # the log's first frame has none
    assert aggregates["epdms"] > 0.5  # the human driver, filtered by itself


def test_human_ec_pairs_with_its_own_plan_half_a_second_earlier(converted: Path) -> None:
    samples = sorted(read_samples(converted), key=lambda s: s["meta"]["timestamp_us"])
    predictions = [predict_human(sample) for sample in samples]
    result = epdms_scorer.EPDMSScorer().score(predictions, samples).table.to_pylist()
    paired = [row for row in result if row["previous_key"] is not None]
    assert paired and all(np.isfinite(row[epdms.EC]) for row in paired)
    first = next(row for row in result if row["previous_key"] is None)
    assert np.isnan(first[epdms.EC])
    scene = scene_from_sample(samples[0])
    assert scene.ego_past is not None and scene.human_poses is not None


def test_validation_callback_logs_epdms(converted: Path) -> None:
    callback = ScoringCallback(converted, metrics=("epdms@navsim-2.2",))
    predictions = [predict_human(sample) for sample in read_samples(converted, fields=("future",))]
    metrics = callback.compute(predictions)
    assert 0.0 <= metrics["val/navsim/epdms"] <= 1.0 and "val/navsim/traffic_light_compliance" in metrics
