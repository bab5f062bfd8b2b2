"""The synthetic NAVSIM logs are a competent driver's: the logged human, scored by the real PDMS / EPDMS scorers on
generated scenes (the three base logs and fresh draws of every route), keeps every rule, as NAVSIM's human agent
does on real logs (PDMS 94.8 on navtest); and the agents are really in its way, so a faster driver is penalised."""

from dataclasses import replace

import numpy as np
import pytest
import yaml

from lead_s2r.convert import convert
from lead_s2r.scoring.baselines import predict_human
from lead_s2r.scoring.navsim import EPDMSScorer, PDMSScorer
from lead_s2r.scoring.navsim.proposals import ReferenceCache
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim as synth
from lead_s2r.synthetic import navsim_map as synth_map
from lead_s2r_adapters.navsim import NavsimAdapter

#: The base logs and one fresh draw on each route; three scenes per log (early, middle, late: the turn).
SPECS = synth.log_specs(6, seed=11)
SCENE_FRAMES = (3, 6, 9)


@pytest.fixture(scope="module")
def samples(tmp_path_factory: pytest.TempPathFactory) -> list[dict]:
    raw = tmp_path_factory.mktemp("expert_raw")
    synth_map.write_map(raw / "maps")
    rng = np.random.default_rng(0)
    logs = {spec.name: synth.write_log(raw, spec, rng) for spec in SPECS}
    tokens = [frames[i]["token"] for frames in logs.values() for i in SCENE_FRAMES]
    path = raw / "scene_filters" / "expert.yaml"
    path.parent.mkdir(parents=True)
    path.write_text(yaml.safe_dump(synth.scene_filter(logs, tokens)))
    out = tmp_path_factory.mktemp("expert_out")
    assert convert(NavsimAdapter(scene_filter=str(path), maps=str(raw / "maps")), raw, out).ok
    return list(read_samples(out, fields=EPDMSScorer.fields))


@pytest.fixture(scope="module")
def references() -> ReferenceCache:
    return ReferenceCache()


def test_the_logged_human_keeps_every_pdms_rule(samples: list[dict], references: ReferenceCache) -> None:
    result = PDMSScorer(reference_cache=references).score([predict_human(s) for s in samples], samples)
    rows = result.table.to_pylist()
    assert len(rows) == len(SPECS) * len(SCENE_FRAMES) and all(row["valid"] for row in rows)
    for row in rows:
        rules = ("no_at_fault_collisions", "drivable_area_compliance", "time_to_collision_within_bound", "comfort")
        assert all(row[name] == 1.0 for name in (*rules, "driving_direction_compliance")), row
        assert row["ego_progress"] > 0.75, row  # near PDM-Closed's progress: it keeps its lane at a human's pace
    assert result.aggregates["pdms"] > 0.9


def test_the_logged_human_keeps_every_epdms_rule(samples: list[dict], references: ReferenceCache) -> None:
    rows = EPDMSScorer(reference_cache=references).score([predict_human(s) for s in samples], samples).table
    for name in ("no_at_fault_collisions", "drivable_area_compliance", "traffic_light_compliance", "lane_keeping"):
        assert set(rows[name].to_pylist()) == {1.0}, name


def test_a_driver_twice_as_fast_runs_into_the_lead_vehicle(samples: list[dict], references: ReferenceCache) -> None:
    """The straight logs with a lead vehicle (those with pedestrians ahead instead: tests/test_perception_worlds.py)."""
    followed = {spec.name for spec in SPECS if spec.brake_at is None}
    straight = [s for s in samples if s["meta"]["extras"]["navsim"]["roadblock_ids"][1] == "201"]  # 101 -> 102
    straight = [s for s in straight if s["meta"]["log_id"] in followed]
    assert len(straight) == 2 * len(SCENE_FRAMES)
    rushed = [replace(p, xy=p.xy * np.array([2.0, 1.0])) for p in map(predict_human, straight)]
    rows = PDMSScorer(reference_cache=references).score(rushed, straight).table.to_pylist()
    assert all(row["no_at_fault_collisions"] == 0.0 or row["time_to_collision_within_bound"] == 0.0 for row in rows)
