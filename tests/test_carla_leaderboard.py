"""carla-metrics on hand-built leaderboard 2.0 results JSON, every number worked by hand from the published formulas."""

import json
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest

from lead_s2r.cli import main
from lead_s2r.scoring.carla_leaderboard import (
    INFRACTIONS,
    ResultsError,
    carla_metrics,
    infraction_score,
    normalised_infraction_score,
    parse_record,
    read_results,
    read_route_ids,
    score_records,
)

VEHICLE_HIT = "Agent collided against object with type=vehicle.tesla.model3 and id=201 at (x=1.0, y=2.0, z=0.0)"


def off_lane(metres: float, pct: float) -> str:
    return f"Agent went outside its route lanes for about {metres} meters ({pct}% of the completed route)"


def slow(pct: float) -> str:
    return f"Average speed is {pct}% of the surrounding traffic's one"


def record(
    route: int | str,
    rc: float = 100.0,
    length: float = 1000.0,
    infractions: dict[str, list[str]] | None = None,
    status: str | None = None,
    rep: int = 0,
) -> dict[str, Any]:
    """One ``_checkpoint.records`` entry as the leaderboard writes it (scores are left for the scorer to recompute)."""
    infractions = {name: [] for name in INFRACTIONS} | (infractions or {})
    return {
        "index": 0,
        "route_id": f"RouteScenario_{route}_rep{rep}",
        "status": status or ("Perfect" if rc >= 100 and not any(infractions.values()) else "Completed"),
        "num_infractions": sum(len(v) for v in infractions.values()),
        "infractions": infractions,
        "scores": {"score_route": rc, "score_penalty": None, "score_composed": None},
        "meta": {"route_length": length, "duration_game": 120.0, "duration_system": 300.0},
    }


def results_file(folder: Path, records: list[dict[str, Any]], name: str = "results.json") -> Path:
    path = folder / name
    path.write_text(json.dumps({"_checkpoint": {"records": records, "progress": [len(records), len(records)]}}))
    return path


def score(records: list[dict[str, Any]], benchmark: str = "longest6", route_ids: list[str] | None = None) -> dict:
    parsed = [parse_record(raw, "test.json", i) for i, raw in enumerate(records)]
    return score_records(parsed, benchmark, route_ids).aggregates


def one(raw: dict[str, Any]):
    return parse_record(raw, "test.json", 0)


def test_one_vehicle_collision_on_a_completed_1km_route():
    hit = one(record(0, infractions={"collisions_vehicle": [VEHICLE_HIT]}))
    assert infraction_score(hit) == pytest.approx(0.6)
    assert normalised_infraction_score(hit) == pytest.approx(0.12)  # (0.2 * 0.6) ** (1 event / 1 km)


# each event type alone on a fully driven 1 km route: leaderboard IS, normalised IS, Bench2Drive success
EXPECTED = {
    "collisions_pedestrian": (0.5, 0.1, False),
    "collisions_vehicle": (0.6, 0.12, False),
    "collisions_layout": (0.65, 0.13, False),
    "red_light": (0.7, 0.14, False),
    "stop_infraction": (0.8, 0.16, False),
    "scenario_timeouts": (0.7, 0.14, False),
    "yield_emergency_vehicle_infractions": (0.7, 0.14, False),
    "route_dev": (1.0, 1.0, False),  # ends the route, no factor
    "vehicle_blocked": (1.0, 1.0, False),
    "route_timeout": (1.0, 1.0, False),
    "outside_route_lanes": (0.75, 0.75, False),  # 25 % of the route off-lane
    "min_speed_infractions": (0.88, 0.88, True),  # 1 - 0.3 * (1 - 0.6); Bench2Drive ignores it
}


@pytest.mark.parametrize("name", INFRACTIONS)
def test_every_infraction_type(name):
    message = {"outside_route_lanes": off_lane(250.0, 25.0), "min_speed_infractions": slow(60.0)}.get(name, "event")
    route = one(record(0, infractions={name: [message]}))
    expected_is, expected_nis, b2d_success = EXPECTED[name]
    assert infraction_score(route) == pytest.approx(expected_is)
    assert normalised_infraction_score(route) == pytest.approx(expected_nis)
    aggregates = score([record(0, infractions={name: [message]})], "bench2drive")
    assert aggregates["sr"] == pytest.approx(100.0 / 220 if b2d_success else 0.0)


def test_events_multiply_and_per_km_normalisation_softens_long_routes():
    route = one(record(0, length=4000.0, infractions={"collisions_vehicle": [VEHICLE_HIT] * 2, "red_light": ["r"]}))
    assert infraction_score(route) == pytest.approx(0.6 * 0.6 * 0.7)
    # 2 hits and 1 red light over 4 driven km
    assert normalised_infraction_score(route) == pytest.approx(0.12 ** (2 / 4) * 0.14 ** (1 / 4))
    half = one(record(0, rc=50.0, length=4000.0, infractions={"collisions_vehicle": [VEHICLE_HIT]}))
    assert normalised_infraction_score(half) == pytest.approx(0.12 ** (1 / 2))  # 2 km driven


def test_min_speed_and_outside_lane_factors():
    route = one(record(0, infractions={"min_speed_infractions": [slow(60.0), slow(90.0)]}))
    assert infraction_score(route) == pytest.approx(0.88 * 0.97)
    assert infraction_score(route, min_speed=False) == 1.0
    lanes = one(record(0, infractions={"outside_route_lanes": [off_lane(100.0, 10.0)]}))
    assert infraction_score(lanes) == pytest.approx(0.9)


def test_the_leaderboards_own_scores_are_compared():
    hit = record(0, rc=80.0, infractions={"collisions_vehicle": [VEHICLE_HIT]})
    hit["scores"] |= {"score_penalty": 0.6, "score_composed": 48.0}
    lanes = record(1, infractions={"outside_route_lanes": [off_lane(12.3, 1.23)]})
    lanes["scores"] |= {"score_penalty": 0.98771, "score_composed": 98.771}  # unrounded 1.229 % off-lane
    assert score([hit, lanes])["max_ds_difference_to_reported"] == pytest.approx(0.001, abs=1e-9)
    assert score([record(0)])["max_ds_difference_to_reported"] is None


def test_a_route_that_was_never_driven_skips_the_per_km_term():
    crashed = one(record(0, rc=0.0, infractions={"collisions_vehicle": [VEHICLE_HIT]}, status="Failed - Agent crashed"))
    assert normalised_infraction_score(crashed) == 1.0


def test_missing_routes_count_zero_and_are_listed():
    records = [record(i) for i in range(36) if i != 7]  # 35 perfect routes of Longest6's 36
    aggregates = score(records, "longest6")
    assert aggregates["ds"] == pytest.approx(3500 / 36)
    assert aggregates["rc"] == pytest.approx(3500 / 36)
    assert aggregates["is"] == pytest.approx(35 / 36)
    assert aggregates["missing_evaluations"] == 1
    named = score(records, "longest6", route_ids=[str(i) for i in range(36)])
    assert named["missing_routes"] == ["7"]


def test_bench2drive_success_rate_ignores_min_speed():
    records = [
        record(1, infractions={"min_speed_infractions": [slow(50.0)]}),  # success
        record(2, infractions={"red_light": ["ran a red light"]}),  # completed, not a success
        record(3, rc=60.0, status="Failed - Agent got blocked"),  # not completed
        record(4),  # success
    ]
    aggregates = score(records, "bench2drive")
    assert aggregates["sr"] == pytest.approx(100 * 2 / 220)
    assert aggregates["ds"] == pytest.approx((100 + 70 + 60 + 100) / 220)  # min speed: no factor on Bench2Drive
    assert score(records, "longest6")["ds"] == pytest.approx((85 + 70 + 60 + 100) / 36)


def test_seeds_pool_as_repetitions():
    first = [record(i) for i in range(20)]
    second = [record(i, rc=50.0) for i in range(20)]
    aggregates = score(first + second, "town13")
    assert aggregates["evaluations_per_route"] == 2
    assert aggregates["ds"] == pytest.approx((20 * 100 + 20 * 50) / 40)
    partial = score(first + second[:19], "town13")
    assert partial["missing_evaluations"] == 1 and partial["missing_routes"] == ["19"]


def test_infractions_per_100km():
    records = [
        record(0, length=1000.0, infractions={"collisions_vehicle": [VEHICLE_HIT]}),
        record(
            1, rc=50.0, length=2000.0, infractions={"red_light": ["r"], "outside_route_lanes": [off_lane(40.0, 4.0)]}
        ),
    ]
    aggregates = score(records, "longest6")
    assert aggregates["km_driven"] == pytest.approx(2.0)
    rates = aggregates["infractions_per_100km"]
    assert set(rates) == set(INFRACTIONS)
    assert rates["collisions_vehicle"] == pytest.approx(50.0)
    assert rates["red_light"] == pytest.approx(50.0)
    assert rates["outside_route_lanes"] == pytest.approx(2.0)  # 0.04 km off-lane over 2 km, per 100 km
    assert rates["collisions_pedestrian"] == 0.0


def test_cli_writes_scores_json_and_parquet(tmp_path):
    batch_a = results_file(tmp_path, [record(i) for i in range(10)], "a.json")
    hit = {"collisions_vehicle": [VEHICLE_HIT]}
    batch_b = results_file(tmp_path, [record(i, infractions=hit) for i in range(10, 19)], "b.json")
    out = tmp_path / "scores"
    assert main(["carla-metrics", str(batch_a), str(batch_b), "--benchmark", "town13", "--out", str(out)]) == 0
    report = json.loads((out / "scores.json").read_text())
    aggregates = report["aggregates"]
    assert report["metric"] == "carla-leaderboard-2.0/town13"
    assert aggregates["ds"] == pytest.approx((10 * 100 + 9 * 60) / 20)
    assert aggregates["nds"] == pytest.approx((10 * 100 + 9 * 12) / 20)
    assert aggregates["nis"] == pytest.approx((10 + 9 * 0.12) / 20)
    assert aggregates["sr"] == pytest.approx(50.0)
    table = pq.read_table(out / "scores.parquet")
    assert table.num_rows == 19
    assert table.column("ds").to_pylist()[-1] == pytest.approx(60.0)


def test_routes_xml_names_the_missing_routes(tmp_path):
    xml = tmp_path / "routes.xml"
    xml.write_text("<routes>" + "".join(f'<route id="{i}" town="Town13"/>' for i in range(20)) + "</routes>")
    results = results_file(tmp_path, [record(i) for i in range(20) if i not in (3, 11)])
    report = carla_metrics([results], "town13", tmp_path / "out", routes_xml=xml)
    assert report["aggregates"]["missing_routes"] == ["3", "11"]


def test_bad_results_name_the_file_and_field(tmp_path):
    broken = record(0)
    del broken["meta"]
    path = results_file(tmp_path, [broken])
    with pytest.raises(ResultsError, match=r"results.json: _checkpoint.records\[0\].*'meta'"):
        read_results(path)
    odd = results_file(tmp_path, [record(0, infractions={"outside_route_lanes": ["went somewhere"]})], "odd.json")
    with pytest.raises(ResultsError, match="for about X meters"):
        carla_metrics([odd], "town13", tmp_path / "out")
    (tmp_path / "empty.json").write_text("{}")
    with pytest.raises(ResultsError, match=r"no _checkpoint\.records"):
        read_results(tmp_path / "empty.json")
    with pytest.raises(ResultsError, match="36"):
        score([record(i) for i in range(37)], "longest6")


def _with(path: tuple[str, ...], value: Any) -> dict[str, Any]:
    """A record with the field at ``path`` set to ``value``."""
    raw = record(0, infractions={"outside_route_lanes": [off_lane(12.5, 3.1)]})
    node = raw
    for name in path[:-1]:
        node = node[name]
    node[path[-1]] = value
    return raw


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("route_id",), 7, r"\[0\]\.route_id is 7, not str"),
        (("route_id",), "", r"\[0\]\.route_id: '' names no route"),
        (("scores",), [], r"\[0\]\.scores is \[\], not dict"),
        (("scores", "score_route"), "x", r"\[0\]\.scores\.score_route is 'x', not float"),
        (("scores", "score_composed"), "x", r"\[0\]\.scores\.score_composed is 'x', not float or null"),
        (("meta", "duration_game"), None, r"\[0\]\.meta\.duration_game is None, not float"),
        (("status",), 7, r"\[0\]\.status is 7, not str"),
        (("infractions",), None, r"\[0\]\.infractions is None, not dict"),
        (("infractions", "red_light"), 7, r"\[0\]\.infractions\.red_light: expected a list of messages"),
        (("infractions", "red_light"), [7], r"\[0\]\.infractions\.red_light: expected a list of messages"),
        (("infractions", "min_speed_infractions"), ["slow"], r"\[0\]\.infractions\.min_speed_infractions: .*X%"),
        (
            ("infractions", "outside_route_lanes"),
            ["off for about 12 m"],
            r"\[0\]\.infractions\.outside_route_lanes: .*X meters",
        ),
    ],
)
def test_a_wrong_typed_field_is_named_with_its_file_and_record(tmp_path, path, value, message):
    """Each was a traceback (AttributeError, TypeError) or a silently different score: a status of 7 read as "7"
    (no success), null infractions as none, an unparsable off-lane message failed later without its file."""
    results = results_file(tmp_path, [_with(path, value)])
    with pytest.raises(ResultsError, match=r"results\.json: _checkpoint\.records" + message):
        read_results(results)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b'{"_checkpoint": {"records": [\xff]}}', "cannot read results JSON: 'utf-8' codec"),
        (b'{"_checkpoint": 7}', r"no _checkpoint\.records list"),
        (b'{"_checkpoint": {"records": [7]}}', r"_checkpoint\.records\[0\] is 7, not a mapping"),
    ],
)
def test_an_unreadable_results_file_is_named(tmp_path, content, message):
    (tmp_path / "results.json").write_bytes(content)
    with pytest.raises(ResultsError, match=r"results\.json: " + message):
        read_results(tmp_path / "results.json")


def test_a_route_id_listed_twice_in_the_routes_xml_is_refused(tmp_path):
    """A damaged id that repeats another would shrink the benchmark's route count: the denominator of every mean."""
    xml = tmp_path / "routes.xml"
    xml.write_text('<routes><route id="0"/><route id="1"/><route id="1"/></routes>')
    with pytest.raises(ResultsError, match=r"routes\.xml: route id\(s\) \['1'\] appear more than once"):
        read_route_ids(xml)
