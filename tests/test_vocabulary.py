"""Trajectory vocabularies on NAVSIM data made by our synthetic generator and converted with maps:
``score_vocabulary`` gives every entry, in every column, the bits it gets scored alone (PDMS and EPDMS);
``lead-s2r vocab score`` writes GTRS's pickle, Parquet and a manifest, the same bytes with workers, on Ray and after
a resumed run; ``vocab build`` is deterministic; bad input is one line, exit 2, nothing written."""

import json
import pickle
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import shapely
import torch

from lead_s2r.cli import main
from lead_s2r.convert import convert
from lead_s2r.data.vocab_scores import VOCAB_SCORES, VOCAB_SCORES_MASK, VocabScores
from lead_s2r.errors import UserError
from lead_s2r.gtrs_targets import EPDMS_NAMES, read_targets
from lead_s2r.schema import MapKind
from lead_s2r.scoring.pdm import epdms, score_proposals, score_vocabulary
from lead_s2r.scoring.pdm.collisions import TTC_OFFSETS, find_hits, step_hits, time_to_collision
from lead_s2r.scoring.pdm.footprint import box_polygons, ego_coords
from lead_s2r.scoring.pdm.map_flags import (
    CELL_CROSSED,
    CELL_SETTLED,
    CLEAR,
    CROSSED,
    INSIDE,
    IS_DRIVABLE,
    IS_LANE,
    BoundsGrid,
    DrivableMap,
    ego_areas,
    multiple_lanes,
)
from lead_s2r.scoring.pdm.observation import log_observation
from lead_s2r.scoring.pdm.overlap import Axes, convex_intersects
from lead_s2r.scoring.pdm.pdm_closed import plan_reference
from lead_s2r.scoring.pdm.rowwise import row_products
from lead_s2r.scoring.pdm.sample import scene_from_sample
from lead_s2r.scoring.pdm.scene import PDMScene
from lead_s2r.scoring.pdm.score import human_trajectory, simulate_rows
from lead_s2r.scoring.pdm.state import StateIndex
from lead_s2r.scoring.pdm.vocabulary import GTRS_INTERVAL_S, GTRS_POSES
from lead_s2r.scoring.vocab_targets import MANIFEST, PARQUET, PARTS, PICKLE, logged_futures
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import navsim
from lead_s2r_adapters.navsim import NavsimAdapter

METRICS = ("pdms@navsim-1.1", "epdms@navsim-2.2")
EP = "ego_progress"
#: GTRS's names (its ``gtrs_agent.py`` losses read them), in SimScale's order
GTRS_EPDMS_NAMES = list(EPDMS_NAMES)


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One synthetic NAVSIM log (7 scenes), converted with maps: ``lead-s2r synth navsim`` + ``convert navsim``."""
    raw, out = tmp_path_factory.mktemp("vocab_raw"), tmp_path_factory.mktemp("vocab_data") / "navsim"
    navsim.generate(raw, count=1, seed=0)
    assert convert(NavsimAdapter(maps=str(raw / "maps")), raw, out).ok
    return out


def arcs(speeds: np.ndarray, curvatures: np.ndarray) -> np.ndarray:
    """Constant-speed arcs in GTRS's layout ``(len(speeds) * len(curvatures), 40, 3)``: stops, crawls, turns that
    leave the road, fast runs into the car ahead."""
    t = GTRS_INTERVAL_S * np.arange(1, GTRS_POSES + 1)
    speed, curvature = np.meshgrid(speeds, curvatures, indexing="ij")
    s = speed.reshape(-1, 1) * t
    k = curvature.reshape(-1, 1) + 1e-9
    heading = k * s
    return np.stack([np.sin(heading) / k, (1 - np.cos(heading)) / k, heading], -1).astype(np.float32)


@pytest.fixture(scope="module")
def vocabulary(converted: Path) -> np.ndarray:
    futures = logged_futures(list(read_samples(converted, fields=("future",))))
    return np.concatenate([arcs(np.array([0.0, 2.0, 6.0, 10.0, 16.0]), np.linspace(-0.12, 0.12, 9)), futures])


@pytest.mark.parametrize("metric", METRICS)
def test_random_entries_equal_scoring_each_alone(converted: Path, vocabulary: np.ndarray, metric: str) -> None:
    """Every column, every sub-score and the final score included, bit for bit (NaN where alone is NaN), with
    chunks of 16 so entries sit at every position of a chunk, simulated 24 at a time so chunks straddle blocks."""
    rng = np.random.default_rng(0)
    varied = set()
    for sample in list(read_samples(converted, fields=("scoring", "boxes", "agents_future", "future")))[:3]:
        scene = scene_from_sample(sample)
        reference = plan_reference(scene)
        together = score_vocabulary(scene, vocabulary, 0.1, reference, metric, chunk=16, simulation_block=24)
        for v in rng.choice(len(vocabulary), size=6, replace=False):
            alone = score_proposals(scene, vocabulary[v : v + 1], 0.1, reference, metric)
            assert together.keys() == alone.keys()
            for name, values in alone.items():
                np.testing.assert_array_equal(together[name][v : v + 1], values, err_msg=f"{name}, entry {v}")
        varied |= {name for name, values in together.items() if len(np.unique(values[np.isfinite(values)])) > 1}
    # the vocabulary exercises the sub-scores: they pass for some entries and fail for others
    assert {"no_at_fault_collisions", "drivable_area_compliance", "ego_progress", "score"} <= varied


def hostile_entries(scene: PDMScene) -> np.ndarray:
    """Entries a k-means vocabulary can hold and a fast path could special-case, ``(V, 40, 3)``: standing still
    (exactly and creeping), reversing (facing forward and backward), far too fast, swerving off the map, changing
    lanes, a U-turn, spinning or flipping heading on the spot, headings past pi, jumps, far off the map, driving into
    every agent at several keyframes (and a metre beside it), standing on map polygons' vertices and sliding along
    their edges."""
    t = GTRS_INTERVAL_S * np.arange(1, GTRS_POSES + 1)
    zero = np.zeros_like(t)

    def entry(x: np.ndarray, y: np.ndarray, heading: np.ndarray | float | None = None) -> np.ndarray:
        x, y = np.broadcast_to(x, t.shape), np.broadcast_to(y, t.shape)
        heading = np.arctan2(np.diff(y, prepend=0.0), np.diff(x, prepend=0.0)) if heading is None else heading
        return np.stack([x, y, np.broadcast_to(heading, t.shape)], -1)

    ramp = np.clip(t / 3.0, 0.0, 1.0)
    entries = [
        entry(zero, zero, 0.0), entry(1e-9 * t, zero, 0.0), entry(-3.0 * t, zero, 0.0), entry(-5.0 * t, zero, np.pi),
        entry(60.0 * t, zero), entry(8.0 * t, 6.0 * t**2), entry(8.0 * t, -6.0 * t**2),
        entry(9.0 * t, 3.5 * (3 * ramp**2 - 2 * ramp**3)), entry(6.0 * np.sin(t), 6.0 * (1 - np.cos(t)), t),
        entry(zero, zero, 2.5 * np.pi * t), entry(5.0 * t, zero, np.where(np.arange(len(t)) % 2, np.pi, 0.0)),
        entry(5.0 * t, zero, 10.0), entry(7.0 * t, np.where(np.arange(len(t)) % 2, 1.0, -1.0)),
        entry(np.where(t > 2.0, 40.0, 0.0), zero, 0.0), entry(1e4 + t, 1e4 + zero, 0.0),
    ]  # fmt: skip
    for track in range(len(scene.agent_poses)):
        for keyframe in (1, 3, 6, 8):
            if keyframe < len(scene.agent_t) and scene.agent_valid[track, keyframe]:
                x, y, _ = scene.agent_poses[track, keyframe]
                reach = np.clip(t / scene.agent_t[keyframe], 0.0, None)
                entries += [entry(x * reach, y * reach), entry(x * reach, y * reach + 1.0)]
    ring_of = np.repeat(np.arange(len(scene.polygon_kind)), np.diff(scene.polygon_offsets))
    near = np.flatnonzero((np.hypot(*scene.polygon_xy.T) < 30.0) & (np.diff(ring_of, append=-1) == 0))[::7]
    for start, end in zip(scene.polygon_xy[near], scene.polygon_xy[near + 1], strict=True):
        heading = np.arctan2(*(end - start)[::-1])
        entries += [entry(start[0] + zero, start[1] + zero, heading)]
        entries += [entry(*(start[:, None] + (end - start)[:, None] * np.clip(t / 4.0, 0.0, 1.0)), heading)]
    return np.stack(entries)


def scene_variants(scene: PDMScene) -> dict[str, PDMScene]:
    """The scene, without agents, with its map moved far away (every point off the grid), its ego standing and
    reversing, sideways and steering."""
    no_agents = {
        "agent_poses": scene.agent_poses[:0], "agent_velocity": scene.agent_velocity[:0],
        "agent_valid": scene.agent_valid[:0], "agent_size": scene.agent_size[:0], "agent_class": scene.agent_class[:0],
    }  # fmt: skip
    return {
        "logged": scene,
        "no agents": replace(scene, **no_agents),
        "map far away": replace(scene, polygon_xy=scene.polygon_xy + 1000.0),
        "ego standing": replace(scene, ego_velocity=np.zeros(2), ego_acceleration=np.zeros(2)),
        "ego reversing": replace(scene, ego_velocity=np.array([-3.0, 0.0]), ego_acceleration=np.array([0.5, 0.1])),
        "ego sideways": replace(scene, ego_velocity=np.array([9.0, 0.4]), tire_steering_angle=0.05),
    }


@pytest.mark.parametrize("metric", METRICS)
def test_hostile_entries_and_scenes_equal_scoring_each_alone(
    converted: Path, vocabulary: np.ndarray, metric: str
) -> None:
    """Every entry of a hostile vocabulary (:func:`hostile_entries`, the logged k-means-like futures, duplicates)
    in every scene variant (:func:`scene_variants`): every column bit for bit what the entry gets alone, with
    chunks of 7 and simulation blocks of 13 (entries at every position, blocks straddled, a short last block)."""
    rng = np.random.default_rng(5)
    samples = list(read_samples(converted, fields=("scoring", "boxes", "agents_future", "future")))
    failing = set()
    for name, scene in scene_variants(scene_from_sample(samples[4])).items():
        reference = plan_reference(scene)
        entries = np.concatenate([hostile_entries(scene), vocabulary[-5:]])
        entries = entries[rng.permutation(np.r_[np.arange(len(entries)), rng.choice(len(entries), 3)])]
        together = score_vocabulary(scene, entries, 0.1, reference, metric, chunk=7, simulation_block=13)
        for v in range(len(entries)):
            alone = score_proposals(scene, entries[v : v + 1], 0.1, reference, metric)
            for column, values in alone.items():
                np.testing.assert_array_equal(together[column][v : v + 1], values, err_msg=f"{name}: {column}, {v}")
        failing |= {column for column, values in together.items() if {0.0, 1.0} <= set(values.tolist())}
    # every sub-score is 0 for some entries and 1 for others (TLC: the entries that run the scene's red light)
    assert set(together) & {*epdms.FILTERED, "comfort"} <= failing


def test_ttc_takes_its_unmoved_overlaps_from_ncs(converted: Path) -> None:
    """TTC's offset-0 queries are NC's boxes at their own steps: taken from :func:`step_hits` they give what TTC
    finds afresh, on hostile entries in every scene variant (standing rows included, which TTC skips), for v1.1's
    steps and v2's."""
    rng = np.random.default_rng(2)
    standing, violations = 0, 0
    variants = scene_variants(first_scene(converted))
    parked = variants["ego standing"]
    poses = parked.agent_poses.copy()
    poses[0] = [2.0, 0.0, 0.0]  # an agent on the standing ego, at every keyframe: overlaps TTC must skip
    variants["agent on the standing ego"] = replace(
        parked, agent_poses=poses, agent_valid=np.ones_like(parked.agent_valid)
    )
    for scene in variants.values():
        states = simulate_rows(scene, hostile_entries(scene), 0.1, plan_reference(scene), None)
        standing += int((np.hypot(states[..., StateIndex.VELOCITY_X], states[..., StateIndex.VELOCITY_Y]) < 5e-3).sum())
        coords = ego_coords(states, scene.vehicle)
        observation = log_observation(scene)
        radius = float(np.hypot(scene.vehicle.length, scene.vehicle.width) / 2)
        hits = step_hits(coords, radius, observation)
        flags = rng.random(states.shape[:2]) < 0.3, rng.random(states.shape[:2]) < 0.3
        for num_steps in (None, states.shape[1] - max(TTC_OFFSETS)):
            fresh = time_to_collision(states, coords, radius, observation, *flags, num_steps=num_steps)
            reused = time_to_collision(
                states, coords, radius, observation, *flags, num_steps=num_steps, hits_at_rest=hits
            )
            for got, expected in zip(reused, fresh, strict=True):
                np.testing.assert_array_equal(got, expected)
            violations += int((fresh[0] == 0.0).sum())
    assert standing > 0 and violations > 0


def test_simulated_rows_must_match_the_proposals(converted: Path, vocabulary: np.ndarray) -> None:
    """``score_proposals(simulated=...)`` scores ``simulate_rows``' rows as it would simulate them, and refuses rows
    that are not those of its proposals (the reference first, the human trajectory last where the filter runs)."""
    scene = first_scene(converted)
    reference = plan_reference(scene)
    entries = vocabulary[:5]
    rows = simulate_rows(scene, entries, 0.1, reference, human_trajectory(scene))
    given = score_proposals(scene, entries, 0.1, reference, "epdms@navsim-2.2", simulated=rows)
    for name, values in score_proposals(scene, entries, 0.1, reference, "epdms@navsim-2.2").items():
        np.testing.assert_array_equal(given[name], values, err_msg=name)
    with pytest.raises(ValueError, match="simulated rows for 4 proposals"):
        score_proposals(scene, entries[:4], 0.1, reference, "epdms@navsim-2.2", simulated=rows)


@pytest.mark.parametrize("metric", METRICS)
def test_vocabulary_wide_progress_is_gtrs_normalisation(converted: Path, vocabulary: np.ndarray, metric: str) -> None:
    sample = next(iter(read_samples(converted, fields=("scoring", "boxes", "agents_future", "future"))))
    scene = scene_from_sample(sample)
    reference = plan_reference(scene)
    pair = score_vocabulary(scene, vocabulary, 0.1, reference, metric)
    wide = score_vocabulary(scene, vocabulary, 0.1, reference, metric, progress="vocabulary", chunk=10)
    normaliser = wide["ep_normaliser_m"]
    assert len(np.unique(normaliser)) == 1 and normaliser[0] == pair["ep_normaliser_m"].max() > 5.0
    raw = pair["progress_m"]
    if metric == "epdms@navsim-2.2":
        np.testing.assert_array_equal(wide["ego_progress"], np.clip(raw / normaliser, 0.0, 1.0))
    else:
        masked = raw * pair["no_at_fault_collisions"] * pair["drivable_area_compliance"]
        np.testing.assert_array_equal(wide["ego_progress"], masked / normaliser)
    assert (wide["ego_progress"] <= pair["ego_progress"]).all()
    assert (wide["score"] <= pair["score"] + 1e-12).all() and (wide["score"] < pair["score"]).any()
    unchanged = set(pair) - {"ego_progress", "ep_normaliser_m", "score"}
    for name in unchanged:
        np.testing.assert_array_equal(wide[name], pair[name], err_msg=name)
    unfiltered = score_vocabulary(scene, vocabulary, 0.1, reference, metric, human_filter=False)
    for v in (0, len(vocabulary) - 1):
        alone = score_proposals(scene, vocabulary[v : v + 1], 0.1, reference, metric, human_filter=False)
        for name, values in alone.items():
            np.testing.assert_array_equal(unfiltered[name][v : v + 1], values, err_msg=f"{name}, entry {v}")


def first_scene(converted: Path) -> PDMScene:
    return scene_from_sample(next(iter(read_samples(converted, fields=("scoring", "boxes", "agents_future")))))


def test_bounds_grid_lists_every_box_holding_a_point() -> None:
    """Points on box edges and corners, on cell borders, a rounding step either side of them and outside the grid:
    the grid's candidates hold every box that holds the point (it only prunes); boxes without bounds hold none."""
    rng = np.random.default_rng(3)
    low = rng.uniform(-40.0, 40.0, (30, 2))
    boxes = np.concatenate([low, low + rng.uniform(0.0, 25.0, (30, 2))], axis=1)
    boxes[7] = np.nan
    boxes[8] = [-45.0, -45.0, -30.0, -30.0]  # the grid's first cell has a member
    grid = BoundsGrid.build(boxes, 2.7)
    finite = boxes[np.isfinite(boxes).all(axis=1)]
    corners = np.concatenate([finite[:, [0, 1]], finite[:, [2, 3]], finite[:, [0, 3]], finite[:, [2, 1]]])
    borders = grid.origin + grid.cell * np.stack([np.arange(40), np.arange(40)[::-1]], axis=1)
    exact = np.concatenate([corners, borders, (finite[:, :2] + finite[:, 2:]) / 2, rng.uniform(-70, 90, (500, 2))])
    points = np.concatenate([exact, np.nextafter(exact, np.inf), np.nextafter(exact, -np.inf)])
    point, entry = grid.candidates(points[:, 0], points[:, 1])
    box = grid.members[entry]
    found = set(zip(point.tolist(), box.tolist(), strict=True))
    x, y = points[:, None, 0], points[:, None, 1]
    holds = (x >= boxes[:, 0]) & (x <= boxes[:, 2]) & (y >= boxes[:, 1]) & (y <= boxes[:, 3])
    truth = set(zip(*(index.tolist() for index in np.nonzero(holds)), strict=True))
    assert truth <= found and 7 not in box
    # points off the grid, on every side, list nothing
    top = grid.origin + grid.cell * np.array(grid.shape)
    off = np.array([[grid.origin[0] - 1.0, 0.0], [0.0, grid.origin[1] - 1e-9], [top[0] + 1.0, 0.0], [0.0, top[1] + 5]])
    assert len(grid.candidates(off[:, 0], off[:, 1])[0]) == 0
    assert len(truth) > 100 and len(found) < 4 * len(truth)


def test_map_lookup_equals_contains_on_every_polygon_edge(converted: Path) -> None:
    """Ego points on the map polygons' vertices and edges (outside: the test is strict), on the grid's cell borders
    and a rounding step either side: the located (point, polygon) pairs are ``contains_xy`` over every polygon, so
    the grid decides nothing a polygon test would decide differently."""
    drivable_map = DrivableMap.from_scene(first_scene(converted))
    rings = shapely.get_coordinates(shapely.get_exterior_ring(drivable_map.polygons))
    grid = drivable_map.grid
    borders = grid.origin + grid.cell * np.stack(np.meshgrid(np.arange(grid.shape[0]), np.arange(9)), -1).reshape(-1, 2)
    spread = np.random.default_rng(5).uniform(grid.origin, grid.origin + grid.cell * np.array(grid.shape), (3000, 2))
    exact = np.concatenate([rings, (rings[1:] + rings[:-1]) / 2, borders, spread])
    points = np.concatenate([exact, np.nextafter(exact, np.inf), np.nextafter(exact, -np.inf)])
    box, polygon = drivable_map.locate(points[:, None, 0], points[:, None, 1])
    assert (np.diff(box) >= 0).all()
    inside = np.stack([shapely.contains_xy(shape, points[:, 0], points[:, 1]) for shape in drivable_map.polygons])
    expected = set(zip(*(index.tolist() for index in np.nonzero(inside.T)), strict=True))
    assert set(zip(box.tolist(), polygon.tolist(), strict=True)) == expected
    assert 0 < len({b for b, _ in expected}) < len(points)
    # cells inside a polygon, clear of one and crossed by one all decided points
    assert {CLEAR, INSIDE, CROSSED} <= set(drivable_map.cover.tolist())


def test_ego_area_flags_equal_polygon_tests_on_every_polygon(converted: Path) -> None:
    """Boxes spread over the map, with corners on polygon vertices and a rounding step off them: every flag of
    ``ego_areas`` equals NAVSIM's definition evaluated with ``contains_xy`` over every polygon (MULTIPLE_LANES: more
    than one lane polygon holds a corner and none holds all four)."""
    scene = first_scene(converted)
    drivable_map = DrivableMap.from_scene(scene)
    rng = np.random.default_rng(11)
    grid = drivable_map.grid
    rings = shapely.get_coordinates(shapely.get_exterior_ring(drivable_map.polygons))
    centers = np.concatenate([
        rng.uniform(grid.origin, grid.origin + grid.cell * np.array(grid.shape), (600, 2)),
        rings[rng.integers(0, len(rings), 200)],
    ])  # fmt: skip
    states = np.zeros((len(centers), 1, 11))
    states[:, 0, :2] = centers
    states[:, 0, 2] = rng.uniform(-np.pi, np.pi, len(centers))
    coords = ego_coords(states, scene.vehicle)
    # a corner exactly on a vertex, and one a rounding step beside it
    coords[-200:, 0, 0] = rings[rng.integers(0, len(rings), 200)]
    coords[-100:, 0, 0] = np.nextafter(coords[-100:, 0, 0], np.inf)
    route = np.asarray(scene.route_lane_ids, np.int64)
    areas = ego_areas(drivable_map, coords, states[..., :2], route)
    points = np.concatenate([coords[:, 0], states[:, :, :2]], axis=1)  # (B, 6, 2): 4 corners, centre, rear axle
    inside = np.stack(
        [shapely.contains_xy(polygon, points[..., 0], points[..., 1]) for polygon in drivable_map.polygons]
    )
    kinds, lanes = drivable_map.kinds[:, None, None], IS_LANE[drivable_map.kinds][:, None]
    lane_corners = inside[:, :, :4] & lanes[..., None]  # (K, B, 4)
    touched = lane_corners.any(axis=2)
    expected = {
        "multiple_lanes": (touched.sum(axis=0) > 1) & ~lane_corners.all(axis=2).any(axis=0),
        "non_drivable_area": ~(inside[:, :, :4] & IS_DRIVABLE[kinds]).any(axis=0).all(axis=1),
        "oncoming_traffic": ~(inside[:, :, 4] & lanes & np.isin(drivable_map.ids, route)[:, None]).any(axis=0),
        "center_in_intersection": (inside[:, :, 4] & (kinds[..., 0] == MapKind.INTERSECTION)).any(axis=0),
        "rear_axle_in_intersection": (inside[:, :, 5] & (kinds[..., 0] == MapKind.INTERSECTION)).any(axis=0),
    }
    for name, flags in expected.items():
        np.testing.assert_array_equal(getattr(areas, name)[:, 0], flags, err_msg=name)
        assert 0 < flags.sum() < len(flags) or name == "rear_axle_in_intersection", name
    # both paths ran: points answered by their cell alone (no polygon edge crosses it) and points located one by one
    assert {CELL_SETTLED, CELL_CROSSED} <= set(drivable_map.settled.state.tolist())


def test_multiple_lanes_counts_distinct_lanes_and_all_four() -> None:
    """Corners held by up to three lane polygons each (-1 pads, repeats across corners, one lane on all four):
    MULTIPLE_LANES is the set definition."""
    rng = np.random.default_rng(2)
    lanes = rng.integers(-1, 5, (4000, 4, 3))
    lanes[:500, :, 1] = 3  # lane 3 holds every corner
    lanes[500:1000] = np.where(rng.random((500, 4, 3)) < 0.7, -1, lanes[500:1000])
    expected = []
    for box in lanes:
        sets = [set(corner[corner >= 0].tolist()) for corner in box]
        expected.append(len(set.union(*sets)) > 1 and not set.intersection(*sets))
    np.testing.assert_array_equal(multiple_lanes(lanes.transpose(1, 2, 0)), expected)
    assert 0 < sum(expected) < len(expected)


def test_collision_candidates_reach_boxes_that_just_touch(converted: Path) -> None:
    """Boxes the size of each agent moved along its edges and diagonal: sharing an edge, touching corner to corner
    (centroids exactly at the pruning bound, the sum of the enclosing radii), a rounding step apart or overlapping.
    NC/TTC's hits are GEOS ``intersects`` against every box of the step."""
    observation = log_observation(first_scene(converted))
    step = 10
    geoms = np.flatnonzero(observation.objects[observation.step_offsets[step] : observation.step_offsets[step + 1]]
                           >= 0) + observation.step_offsets[step]  # fmt: skip
    corners = observation.corners[geoms]
    shifts = [corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 1], corners[:, 2] - corners[:, 0]]
    moved = [corners + shift[:, None] * scale for shift in shifts for scale in (1.0, 1.0 - 1e-12, 1.0 + 1e-12)]
    coords = np.concatenate([np.concatenate([box, box.mean(axis=1, keepdims=True)], axis=1) for box in moved])
    radius = float(observation.radius[geoms].max())
    centers = coords[None, :, -1]  # one query slot, a row per box
    query, geom = find_hits(
        observation, centers[..., 0], centers[..., 1], np.array([step]), lambda q: coords[q], radius
    )
    polygons = box_polygons(coords)
    truth = {
        (q, int(g))
        for q in range(len(coords))
        for g in geoms
        if shapely.intersects(polygons[q], observation.polygons[g])
    }
    assert set(zip(query.tolist(), geom.tolist(), strict=True)) == truth
    assert len(truth) >= len(coords) // 3
    # each moved box against the agent it was moved from: the observation's axes, gathered per pair, are the numbers
    # the pair's own corners give, and the test answers GEOS with them
    pairs = np.tile(geoms, len(moved))
    gathered = observation.axes[pairs]
    recomputed = Axes.of(observation.corners[pairs])
    for name in ("nx", "ny", "low", "high"):
        assert getattr(gathered, name).tobytes() == getattr(recomputed, name).tobytes()

    def exact(undecided: np.ndarray) -> np.ndarray:
        return shapely.intersects(polygons[undecided], observation.polygons[pairs[undecided]])

    answer = convex_intersects(coords[:, :4], observation.corners[pairs], exact, gathered)
    assert answer.tolist() == [(q, int(g)) in truth for q, g in enumerate(pairs.tolist())]


def test_separating_axes_leave_a_degenerate_outline_to_geos() -> None:
    """A box collapsed to a point has no edge normals (NaN gaps): a gap on the other box's axes still separates it
    when it lies outside, and inside it goes to GEOS instead of counting as overlap (the NaN axes prove nothing)."""
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    points = np.array([[1.0, 1.0], [5.0, 1.0]])  # inside the square, beyond it on its x axis
    first = np.repeat(points[:, None], 4, axis=1)
    second = np.stack([square, square])
    asked = []

    def exact(undecided: np.ndarray) -> np.ndarray:
        asked.extend(undecided.tolist())
        return shapely.intersects(shapely.points(points[undecided]), shapely.polygons(second[undecided]))

    assert convex_intersects(first, second, exact).tolist() == [True, False]
    assert asked == [0]


def vocab_score(vocab: Path, data: Path, out: Path, *options: str) -> dict[str, bytes]:
    """Every file ``vocab score`` writes, by name."""
    args = ["vocab", "score", "--vocab", str(vocab), "--data", str(data), "--out", str(out), "--quiet"]
    assert main([*args, "--metric", "epdms@navsim-2.2", *options]) == 0
    return {path.name: path.read_bytes() for path in sorted(out.iterdir()) if path.is_file()}


@pytest.fixture(scope="module")
def vocab_file(tmp_path_factory: pytest.TempPathFactory, vocabulary: np.ndarray) -> Path:
    path = tmp_path_factory.mktemp("vocab") / "vocab.npy"
    np.save(path, vocabulary[::4])
    return path


@pytest.fixture(scope="module")
def scored(tmp_path_factory: pytest.TempPathFactory, vocab_file: Path, converted: Path) -> dict[str, bytes]:
    return vocab_score(vocab_file, converted, tmp_path_factory.mktemp("scored") / "one")


def test_vocab_score_writes_gtrs_pickle_parquet_and_manifest(scored, vocab_file, converted, tmp_path) -> None:
    size = len(np.load(vocab_file))
    targets = pickle.loads(scored[PICKLE])
    samples = list(read_samples(converted, fields=()))
    tokens = [sample["meta"]["extras"]["navsim"]["scene_token"] for sample in samples]
    assert list(targets) == tokens  # NAVSIM's scene tokens, in data order
    assert {"traffic_light_compliance", "lane_keeping", "history_comfort", "pdm_score"} <= set(GTRS_EPDMS_NAMES)
    assert len(GTRS_EPDMS_NAMES) == 9 and GTRS_EPDMS_NAMES[-1] == "pdm_score"
    for columns in targets.values():
        assert list(columns) == GTRS_EPDMS_NAMES
        assert all(values.dtype == np.float16 and values.shape == (size,) for values in columns.values())
    (tmp_path / PICKLE).write_bytes(scored[PICKLE])
    assert read_targets(tmp_path / PICKLE).keys() == targets.keys()
    table = pq.read_table(pa.BufferReader(scored[PARQUET]))
    assert table.column_names == ["key", "token", *GTRS_EPDMS_NAMES] and table.num_rows == len(tokens)
    first = table.slice(0, 1).to_pylist()[0]
    np.testing.assert_array_equal(np.float16(first["pdm_score"]), targets[first["token"]]["pdm_score"])
    manifest = json.loads(scored[MANIFEST])
    assert manifest["complete"] and manifest["scenes"] == len(tokens) and manifest["entries"] == size
    assert manifest["identity"]["metric"] == "epdms@navsim-2.2" and manifest["failed"] == []
    assert manifest["identity"]["shape"] == [size, GTRS_POSES, 3] and manifest["gtrs_metrics"] == GTRS_EPDMS_NAMES


def test_workers_and_a_resumed_run_write_the_same_bytes(scored, vocab_file, converted, tmp_path) -> None:
    assert vocab_score(vocab_file, converted, tmp_path / "two", "--workers", "2") == scored
    resumed = tmp_path / "resumed"
    vocab_score(vocab_file, converted, resumed)
    parts = sorted((resumed / PARTS).iterdir())
    parts[1].unlink()  # as if killed before that job ended
    (resumed / PICKLE).unlink()
    before = {path: path.stat().st_mtime_ns for path in parts if path.exists()}
    assert vocab_score(vocab_file, converted, resumed) == scored
    assert all(path.stat().st_mtime_ns == mtime for path, mtime in before.items())  # finished jobs not redone


def test_vocab_build_is_seeded_and_in_gtrs_layout(converted: Path, tmp_path: Path) -> None:
    paths = [tmp_path / f"{name}.npy" for name in ("a", "b", "c")]
    for path, seed in zip(paths, (0, 0, 1), strict=True):
        args = ["vocab", "build", "--data", str(converted), "--size", "4", "--out", str(path), "--seed", str(seed)]
        assert main(args) == 0
    a = np.load(paths[0])
    assert a.shape == (4, GTRS_POSES, 3) and a.dtype == np.float32 and np.isfinite(a).all()
    assert paths[0].read_bytes() == paths[1].read_bytes()
    futures = logged_futures(list(read_samples(converted, fields=("future",))))
    assert np.abs(a[:, -1, 0]).max() <= np.abs(futures[:, -1, 0]).max() + 1e-3  # centres of the logged futures


def expect_user_error(args: list[str], out: Path, capsys: pytest.CaptureFixture[str], match: str) -> None:
    """One line on stderr naming the problem, exit status 2, nothing written to ``out``."""
    before = sorted(out.rglob("*")) if out.exists() else None
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err, err
    assert (sorted(out.rglob("*")) if out.exists() else None) == before


def test_bad_input_is_one_line_and_writes_nothing(converted, vocab_file, toy_data, tmp_path, capsys) -> None:
    out = tmp_path / "out"
    score = ["vocab", "score", "--data", str(converted), "--out", str(out), "--quiet", "--vocab"]
    wrong_shape = tmp_path / "wrong.npy"
    np.save(wrong_shape, np.zeros((8, 40, 2), np.float32))
    expect_user_error([*score, str(wrong_shape)], out, capsys, "(V, K, 3)")
    with_nan = tmp_path / "nan.npy"
    poses = np.load(vocab_file)
    poses[2, 5, 1] = np.nan
    np.save(with_nan, poses)
    expect_user_error([*score, str(with_nan)], out, capsys, "entry 2")
    no_scoring = ["vocab", "score", "--vocab", str(vocab_file), "--data", toy_data, "--out", str(out), "--quiet"]
    expect_user_error(no_scoring, out, capsys, "no field 'scoring'")
    out.mkdir()
    (out / PICKLE).write_bytes(pickle.dumps({"not": "ours"}))
    expect_user_error([*score, str(vocab_file)], out, capsys, "not ours")
    with pytest.raises(UserError, match="1-D array"):
        read_targets(out / PICKLE)
    (out / "list.pkl").write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(UserError, match="not a dict by token"):
        read_targets(out / "list.pkl")


def test_executor_ray_writes_the_bytes_of_one_process(scored, vocab_file, converted, tmp_path) -> None:
    pytest.importorskip("ray")
    from ray_cluster import two_node_cluster

    with two_node_cluster() as cluster:
        ray = vocab_score(vocab_file, converted, tmp_path / "ray", "--executor", "ray", "--address", cluster.address)
    assert ray == scored


def test_navsim_samples_get_their_scenes_vocabulary_targets(scored, converted, tmp_path) -> None:
    """``SourceSpec(vocab_scores=...)``: each sample gets its scene's (M, V) targets, masked where the pickle has none;
    the pickle is not shipped to loader workers with the pipeline."""
    path = tmp_path / PICKLE
    path.write_bytes(scored[PICKLE])
    targets = pickle.loads(scored[PICKLE])
    attach = VocabScores(path)
    sample = next(iter(read_samples(converted, fields=())))
    out = attach(sample, {})
    columns = targets[sample["meta"]["extras"]["navsim"]["scene_token"]]
    assert out[VOCAB_SCORES].dtype == torch.float32 and out[VOCAB_SCORES].shape == (len(columns), len(columns[EP]))
    np.testing.assert_array_equal(out[VOCAB_SCORES][GTRS_EPDMS_NAMES.index(EP)].numpy(), columns[EP])
    assert bool(out[VOCAB_SCORES_MASK])
    stranger = {"__key__": "x", "meta": {"extras": {"navsim": {"scene_token": "not-scored"}}}}
    missing = pickle.loads(pickle.dumps(attach))(stranger, {})
    assert not bool(missing[VOCAB_SCORES_MASK]) and not missing[VOCAB_SCORES].any()
    assert missing[VOCAB_SCORES].shape == out[VOCAB_SCORES].shape
    assert len(pickle.dumps(attach)) < 1000  # the path, not the targets


@pytest.mark.parametrize("strided", [False, True])
@pytest.mark.parametrize("shape", [(40, 40), (10, 5)])
def test_row_products_do_not_depend_on_the_rows_beside_them(strided: bool, shape: tuple[int, int]) -> None:
    """A row multiplied among 1,025 others, alone, and alone at another memory alignment, in the same layout: the
    same bits, for contiguous rows (a BLAS product per row: the speed fit) and strided ones (numpy's own loop: the
    curvature lookahead, Savitzky-Golay on a state column). The layout itself may change the bits (it picks the
    loop), so the vocabulary and a single entry must reach each product with the same layout, as they do."""
    rng = np.random.default_rng(8)
    matrix = rng.normal(size=shape)
    step = 3 if strided else 1

    def rows(count: int, offset: int = 0) -> np.ndarray:
        """``(count, K)`` rows in a fresh buffer starting ``offset`` bytes in, every ``step``-th value."""
        size = count * shape[0] * step
        buffer = np.frombuffer(bytearray(size * 8 + offset), np.float64, count=size, offset=offset)
        return buffer.reshape(count, -1)[:, ::step]

    values = rows(1025)
    values[:] = rng.normal(size=values.shape)
    together = row_products(values, matrix)
    for row in (0, 1, 511, 1024):
        for offset in (0, 8, 24):
            alone = rows(1, offset)
            alone[:] = values[row]
            assert row_products(alone, matrix).tobytes() == together[row : row + 1].tobytes(), (row, offset)
