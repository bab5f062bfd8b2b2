"""CARLA leaderboard 2.0 results JSON -> DS, RC, IS, Bench2Drive SR, Town13 NDS/NIS and infractions per 100 km.

No CARLA import: everything is recomputed from the records of ``_checkpoint.records`` (route completion, route length,
infraction messages), so a result file from any leaderboard fork scores the same way and a hand-built file tests it.

Traps this module exists to get right:

- The denominator is the **benchmark's** route count (Bench2Drive 220, Longest6 v2 36, Town13 validation 20), not the
  number of records: a route that crashed the evaluation and left no record counts 0 in DS, RC and IS (the
  leaderboard's ``scores_mean`` divides by ``total_routes`` the same way).
- Several files are pooled: seeds (each file holds every route once) or route batches (each file holds some routes).
  Every record is one evaluation; a route evaluated in k files counts k times and the denominator is the route count
  times the most evaluations any route got, so three seeds give the mean over seeds. Do not pass overlapping batches.
- The infraction score multiplies one factor per event; min-speed and outside-lane events carry a percentage in their
  message, which is the only place the results JSON keeps it. Bench2Drive marks min speed ``unused``: no factor, and
  its success rate ignores those events.
- Town13's normalised infraction score (NIS, "Hidden Biases") raises ``0.2 * p`` to the events per driven km, so one
  vehicle hit on a fully driven 1 km route gives 0.12 where the leaderboard IS gives 0.6.
- Infractions per km divide counts by the km actually driven (route length x RC, at least 1 m); off-lane is a distance,
  so its "per 100 km" entry is off-lane km per 100 km driven.
"""

import json
import re
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyarrow as pa

from lead_s2r.errors import UserError
from lead_s2r.fields import check_fields, fits
from lead_s2r.scoring.base import ScoreResult
from lead_s2r.scoring.scores_file import ScoresFile

METRIC_VERSION = "1"

#: Routes in each benchmark: the denominator of every average.
BENCHMARK_ROUTES = {"bench2drive": 220, "longest6": 36, "town13": 20}

#: The leaderboard's infraction names, in its own order (``statistics_manager.py``).
INFRACTIONS = (
    "collisions_layout",
    "collisions_pedestrian",
    "collisions_vehicle",
    "red_light",
    "stop_infraction",
    "outside_route_lanes",
    "min_speed_infractions",
    "yield_emergency_vehicle_infractions",
    "scenario_timeouts",
    "route_dev",
    "vehicle_blocked",
    "route_timeout",
)

#: Leaderboard 2.0 penalty per event (``PENALTY_*`` constants); the route-ending events have none.
PENALTIES = {
    "collisions_pedestrian": 0.5,
    "collisions_vehicle": 0.6,
    "collisions_layout": 0.65,
    "red_light": 0.7,
    "stop_infraction": 0.8,
    "scenario_timeouts": 0.7,
    "yield_emergency_vehicle_infractions": 0.7,
}
MIN_SPEED_PENALTY = 0.7  # factor = 1 - (1 - 0.7) * (1 - pct / 100)
NIS_SCALE = 0.2  # "Hidden Biases" normalisation multiplies each penalty base by 0.2
SUCCESS_STATUSES = ("Completed", "Perfect")

_OUTSIDE_LANES = re.compile(r"for about ([\d.eE+-]+) meters \(([\d.eE+-]+)% of the completed route\)")
_MIN_SPEED = re.compile(r"is ([\d.eE+-]+)% of the surrounding traffic")
_ROUTE_ID = re.compile(r"^(?:RouteScenario_)?(.+?)(?:_rep(\d+))?$")
#: The types of the record fields the scores read (:func:`lead_s2r.fields.check_fields`).
RECORD_FIELDS = {"route_id": str, "scores": dict, "meta": dict, "status": str, "infractions": dict}
SCORES_FIELDS = {"score_route": float, "score_composed": float | None, "score_penalty": float | None}
META_FIELDS = {"route_length": float, "duration_game": float}
_ADVICE = "is this a leaderboard 2.0 results file?"


class ResultsError(UserError, ValueError):
    """A results JSON that cannot be read as leaderboard 2.0 output; the message names the file and field."""


@dataclass(frozen=True)
class RouteRecord:
    """One evaluated route, as the leaderboard recorded it."""

    source: str
    route_id: str
    route: str
    repetition: int
    status: str
    route_completion: float  # percent
    route_length: float  # metres
    duration_game: float  # seconds
    infractions: dict[str, list[str]] = field(default_factory=dict)
    reported_ds: float | None = None
    reported_is: float | None = None

    def count(self, name: str) -> int:
        return len(self.infractions.get(name, ()))

    @property
    def driven_km(self) -> float:
        return self.route_completion / 100.0 * self.route_length / 1000.0


def outside_lane_event(message: str) -> tuple[float, float]:
    """(metres off-lane, percent of the completed route) from an ``outside_route_lanes`` message."""
    match = _OUTSIDE_LANES.search(message)
    if match is None:
        raise ResultsError(f"outside_route_lanes message without 'for about X meters (Y% ...)': {message!r}")
    return float(match.group(1)), float(match.group(2))


def min_speed_percentage(message: str) -> float:
    """The ego's mean speed as a percent of the surrounding traffic's, from a ``min_speed_infractions`` message."""
    match = _MIN_SPEED.search(message)
    if match is None:
        raise ResultsError(f"min_speed_infractions message without 'is X% of the surrounding traffic': {message!r}")
    return float(match.group(1))


def percentage_factors(record: RouteRecord, min_speed: bool = True) -> float:
    """The product of the min-speed factors (skipped with ``min_speed=False``) and the outside-lane factor."""
    factor = 1.0
    if min_speed:
        for message in record.infractions.get("min_speed_infractions", ()):
            factor *= 1.0 - (1.0 - MIN_SPEED_PENALTY) * (1.0 - min_speed_percentage(message) / 100.0)
    for message in record.infractions.get("outside_route_lanes", ()):
        factor *= 1.0 - outside_lane_event(message)[1] / 100.0
    return factor


def infraction_score(record: RouteRecord, min_speed: bool = True) -> float:
    """Leaderboard 2.0 IS of one route: the product of one factor per event (``min_speed=False``: Bench2Drive)."""
    score = percentage_factors(record, min_speed)
    for name, penalty in PENALTIES.items():
        score *= penalty ** record.count(name)
    return score


def normalised_infraction_score(record: RouteRecord) -> float:
    """Town13's NIS: ``prod_j (0.2 p_j) ** (n_j / driven km)`` times the min-speed and outside-lane factors."""
    score = percentage_factors(record)
    km = record.driven_km
    if km > 0:
        for name, penalty in PENALTIES.items():
            score *= (NIS_SCALE * penalty) ** (record.count(name) / km)
    return score


def is_success(record: RouteRecord) -> bool:
    """Bench2Drive success: the route was completed and nothing but min-speed events happened."""
    clean = all(not record.infractions.get(name) for name in INFRACTIONS if name != "min_speed_infractions")
    return record.status in SUCCESS_STATUSES and clean


def _infractions(raw: dict[str, Any], where: str) -> dict[str, list[str]]:
    """The infraction messages by type; those whose percentage the scores read (off-lane, min speed) are parsed here,
    where the file and record are known."""
    infractions = raw.get("infractions", {})
    unknown = set(infractions) - set(INFRACTIONS)
    if unknown:
        raise ResultsError(f"{where}: unknown infraction type(s) {sorted(unknown)}; known: {list(INFRACTIONS)}")
    parsers = {"outside_route_lanes": outside_lane_event, "min_speed_infractions": min_speed_percentage}
    for name, messages in infractions.items():
        if not fits(messages, list[str]):
            raise ResultsError(f"{where}.infractions.{name}: expected a list of messages, got {messages!r}")
        for message in messages if name in parsers else ():
            try:
                parsers[name](message)
            except ResultsError as err:
                raise ResultsError(f"{where}.infractions.{name}: {err}") from None
    return {name: list(messages) for name, messages in infractions.items()}


def parse_record(raw: Any, source: str, position: int) -> RouteRecord:
    """One entry of ``_checkpoint.records``; errors name the file, record and field."""
    at = f"_checkpoint.records[{position}]"
    raw = check_fields(raw, RECORD_FIELDS, source, ResultsError, _ADVICE, at, ("route_id", "scores", "meta"))
    scores = check_fields(raw["scores"], SCORES_FIELDS, source, ResultsError, _ADVICE, f"{at}.scores", ("score_route",))
    meta = check_fields(raw["meta"], META_FIELDS, source, ResultsError, _ADVICE, f"{at}.meta", ("route_length",))
    match = _ROUTE_ID.match(raw["route_id"])
    if match is None:
        raise ResultsError(f"{source}: {at}.route_id: {raw['route_id']!r} names no route")
    return RouteRecord(
        source=source,
        route_id=raw["route_id"],
        route=match.group(1),
        repetition=int(match.group(2) or 0),
        status=raw.get("status", "").split(" - ")[0],
        route_completion=float(scores["score_route"]),
        route_length=float(meta["route_length"]),
        duration_game=float(meta.get("duration_game", 0.0)),
        infractions=_infractions(raw, f"{source}: {at}"),
        reported_ds=_optional_float(scores.get("score_composed")),
        reported_is=_optional_float(scores.get("score_penalty")),
    )


def _optional_float(value: float | None) -> float | None:
    return None if value is None else float(value)


def read_results(path: str | Path) -> list[RouteRecord]:
    """The route records of one leaderboard results JSON (``_checkpoint.records``)."""
    path = Path(path)
    try:
        content = json.loads(path.read_bytes())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ResultsError(f"{path}: cannot read results JSON: {err}") from None
    checkpoint = content.get("_checkpoint") if isinstance(content, dict) else None
    records = checkpoint.get("records") if isinstance(checkpoint, dict) else None
    if not isinstance(records, list):
        raise ResultsError(f"{path}: no _checkpoint.records list; pass the leaderboard's --checkpoint JSON")
    return [
        parse_record(raw, str(path), i)
        for i, raw in enumerate(records)
        if not isinstance(raw, dict) or raw.get("index", 0) != -1
    ]


def read_route_ids(path: str | Path) -> list[str]:
    """Route ids of a leaderboard routes XML (``<route id="...">``), to list the routes that have no result."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as err:
        raise ResultsError(f"{path}: cannot read routes XML: {err}") from None
    ids = [route.get("id") for route in root.iter("route")]
    if not ids or None in ids:
        raise ResultsError(f"{path}: expected <route id=...> elements, found {len(ids)} (some without id)")
    repeated = sorted(name for name, count in Counter(ids).items() if count > 1)
    if repeated:
        raise ResultsError(f"{path}: route id(s) {repeated[:5]} appear more than once; each route has its own id")
    return [str(i) for i in ids]


def _route_row(record: RouteRecord, benchmark: str) -> dict[str, Any]:
    score = infraction_score(record, min_speed=benchmark != "bench2drive")
    nis = normalised_infraction_score(record)
    row = {
        "source": record.source,
        "route_id": record.route_id,
        "route": record.route,
        "repetition": record.repetition,
        "status": record.status,
        "rc": record.route_completion,
        "is": score,
        "ds": max(record.route_completion * score, 0.0),
        "nis": nis,
        "nds": record.route_completion * nis,
        "success": is_success(record),
        "route_length_m": record.route_length,
        "driven_km": record.driven_km,
        "duration_game_s": record.duration_game,
        "outside_lane_m": sum(outside_lane_event(m)[0] for m in record.infractions.get("outside_route_lanes", ())),
        "reported_ds": record.reported_ds,
        "reported_is": record.reported_is,
    }
    return row | {name: record.count(name) for name in INFRACTIONS}


def infractions_per_100km(rows: Sequence[dict[str, Any]]) -> tuple[float, dict[str, float]]:
    """(km driven, per-100-km rate of every infraction type); off-lane is km off-lane per 100 km driven."""
    km = max(sum(row["driven_km"] for row in rows), 0.001)  # the leaderboard's floor
    rates = {name: 100.0 * sum(row[name] for row in rows) / km for name in INFRACTIONS}
    rates["outside_route_lanes"] = 100.0 * sum(row["outside_lane_m"] for row in rows) / 1000.0 / km
    return km, rates


def score_records(
    records: Iterable[RouteRecord], benchmark: str, route_ids: Sequence[str] | None = None
) -> ScoreResult:
    """Aggregate route records over the benchmark's routes (missing routes count 0; see the module docstring).

    ``route_ids`` (from the benchmark's routes XML) name the missing routes; without them only their number is known.
    """
    if benchmark not in BENCHMARK_ROUTES:
        raise ResultsError(f"unknown benchmark {benchmark!r}; use one of {sorted(BENCHMARK_ROUTES)}")
    rows = [_route_row(record, benchmark) for record in records]
    routes = len(route_ids) if route_ids is not None else BENCHMARK_ROUTES[benchmark]
    evaluations = Counter(row["route"] for row in rows)
    if route_ids is not None:
        unknown = sorted(set(evaluations) - set(route_ids))
        if unknown:
            raise ResultsError(f"results hold route(s) {unknown[:5]} that the routes XML does not list")
    repetitions = max(evaluations.values(), default=1)
    if len(evaluations) > routes:
        raise ResultsError(f"results hold {len(evaluations)} distinct routes but {benchmark} has {routes}")
    denominator = routes * repetitions
    missing = denominator - len(rows)
    km, rates = infractions_per_100km(rows)

    def mean(key: str) -> float:
        return float(sum(float(row[key]) for row in rows) / denominator)

    aggregates = {
        "benchmark": benchmark,
        "ds": mean("ds"),
        "rc": mean("rc"),
        "is": mean("is"),
        "sr": 100.0 * mean("success"),
        "nds": mean("nds"),
        "nis": mean("nis"),
        "km_driven": km,
        "infractions_per_100km": rates,
        "routes": routes,
        "evaluations_per_route": repetitions,
        "records": len(rows),
        "missing_evaluations": missing,
        "missing_routes": _missing_routes(evaluations, repetitions, route_ids),
        "max_ds_difference_to_reported": _max_difference(rows, "ds", "reported_ds"),
    }
    return ScoreResult(pa.Table.from_pylist(rows) if rows else pa.table({}), aggregates)


def _max_difference(rows: Sequence[dict[str, Any]], ours: str, theirs: str) -> float | None:
    """Largest |recomputed - leaderboard's own| over the records that carry the leaderboard's value: a check that the
    results come from the leaderboard version these formulas describe (None: no record carries one)."""
    pairs = [(row[ours], row[theirs]) for row in rows if isinstance(row[theirs], int | float)]
    return max((abs(a - b) for a, b in pairs), default=None)


def _missing_routes(evaluations: Counter, repetitions: int, route_ids: Sequence[str] | None) -> list[str]:
    """Routes with fewer evaluations than the others: by id where the routes XML is known, else those seen short."""
    ids = list(route_ids) if route_ids is not None else sorted(evaluations)
    return [route for route in ids if evaluations.get(route, 0) < repetitions]


def carla_metrics(
    results: Sequence[str | Path], benchmark: str, out: str | Path, routes_xml: str | Path | None = None
) -> dict[str, Any]:
    """The body of ``lead-s2r carla-metrics``: score results JSON files, write ``scores.json`` / ``scores.parquet``."""
    from lead_s2r import __version__

    if not results:
        raise ResultsError("no results JSON given")
    records = [record for path in results for record in read_results(path)]
    route_ids = read_route_ids(routes_xml) if routes_xml is not None else None
    result = score_records(records, benchmark, route_ids)
    report = {
        "metric": f"carla-leaderboard-2.0/{benchmark}",
        "metric_version": METRIC_VERSION,
        "package_version": __version__,
        "config": {"benchmark": benchmark, "routes_xml": None if routes_xml is None else str(routes_xml)},
        "results": [str(path) for path in results],
        "aggregates": result.aggregates,
    }
    return ScoresFile(Path(out), report, result.table).write()
