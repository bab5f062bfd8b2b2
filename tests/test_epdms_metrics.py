"""EPDMS v2.2 specifics on hand-built scenes with hand-worked numbers: TLC, LK, DDC, EP, HC, EC, log replay."""

import dataclasses

import numpy as np
import pytest
import shapely
from pdm_scenes import TIMES, agent, drive, road_scene

from lead_s2r.schema import BoxClass, MapKind
from lead_s2r.scoring.pdm import epdms
from lead_s2r.scoring.pdm.comfort import center_frame, history_comfort, past_states
from lead_s2r.scoring.pdm.footprint import ego_coords
from lead_s2r.scoring.pdm.metrics import (
    LANE_KEEPING_LIMIT_M,
    beyond_lane_limit,
    driving_direction_compliance,
    ego_progress_v2,
    lane_keeping,
)
from lead_s2r.scoring.pdm.observation import V2_STEPS, log_observation, overlapping_ego_at_t0
from lead_s2r.scoring.pdm.scene import PDMScene, PreviousFrame
from lead_s2r.scoring.pdm.score import EPDMS_METRIC, score_proposals, score_states_v2
from lead_s2r.scoring.pdm.state import StateIndex
from lead_s2r.scoring.pdm.traffic_lights import on_red_light, red_light_polygons, traffic_light_compliance
from lead_s2r.scoring.pdm.vehicle import PACIFICA

CONNECTOR = 31  # a lane connector over the ego lane, x in [20, 30]
KEYFRAMES_V2 = np.arange(9) * 0.5


def with_connector(scene: PDMScene, red_at: list[bool], on_route: bool) -> PDMScene:
    """The road with lane connector 31 (x 20..30 on lane 11), red at the keyframes where ``red_at`` holds."""
    ring = np.array([[20.0, -1.75], [30.0, -1.75], [30.0, 1.75], [20.0, 1.75]])
    red = [[CONNECTOR] if r else [] for r in red_at]
    return dataclasses.replace(
        scene,
        polygon_xy=np.concatenate([scene.polygon_xy, ring]),
        polygon_offsets=np.append(scene.polygon_offsets, scene.polygon_offsets[-1] + 4),
        polygon_id=np.append(scene.polygon_id, CONNECTOR),
        polygon_kind=np.append(scene.polygon_kind, MapKind.LANE_CONNECTOR),
        red_light_t=KEYFRAMES_V2[: len(red_at)],
        red_light_ids=np.array([i for ids in red for i in ids], np.int64),
        red_light_offsets=np.concatenate([[0], np.cumsum([len(ids) for ids in red])]).astype(np.int64),
        light_route_lane_ids=np.array([11, CONNECTOR] if on_route else [11]),
    )


def cruise(speed: float, count: int = 8, interval: float = 0.5) -> np.ndarray:
    t = interval * np.arange(1, count + 1)
    return np.stack([speed * t, np.zeros(count), np.zeros(count)], -1)


def v2(scene: PDMScene, *rows: np.ndarray) -> dict[str, np.ndarray]:
    return score_states_v2(scene, np.concatenate(rows), log_observation(scene, V2_STEPS, replay=True), None)


@pytest.mark.parametrize(("on_route", "expected"), [(True, 0.0), (False, 1.0)])
def test_red_light_crossed_on_route_fails_off_route_does_not(on_route: bool, expected: float) -> None:
    scene = with_connector(road_scene(), [True] * 9, on_route)
    scores = v2(scene, drive(10.0 * TIMES))  # rear axle 0 -> 40 m, front bumper reaches x = 20 at t = 1.6 s
    assert scores[epdms.TLC][0] == expected
    assert scores[epdms.DDC][0] == 1.0 and scores[epdms.NC][0] == 1.0  # a red light is no collision
    if on_route:  # the front bumper (rear axle + 4.049 m) passes x = 20 between 1.5 and 1.6 s
        assert int(np.argmax(scores["on_red_light"][0])) == 16


def test_red_light_status_is_held_five_steps_and_step_zero_counts() -> None:
    scene = with_connector(road_scene(), [False, True, False], on_route=True)
    lights = red_light_polygons(scene, V2_STEPS)
    assert [len(step) for step in lights[:16]] == [0] * 5 + [1] * 5 + [0] * 6  # keyframe 1 rules steps 5..9
    assert all(len(step) == 0 for step in lights[16:])  # after the last keyframe its status holds (green)
    standing = np.zeros((1, V2_STEPS, 11))
    standing[..., StateIndex.X] = 22.0  # parked on the connector
    touching = on_red_light(ego_coords(standing, PACIFICA), lights)
    assert np.flatnonzero(touching[0]).tolist() == [5, 6, 7, 8, 9]
    assert traffic_light_compliance(touching).tolist() == [0.0]
    red_now = red_light_polygons(with_connector(road_scene(), [True], on_route=True), V2_STEPS)
    assert on_red_light(ego_coords(standing, PACIFICA), red_now)[0].all()  # step 0 included


def test_red_light_bounds_prune_keeps_boxes_touching_at_the_bounds() -> None:
    """Boxes touching a (diamond) light only at the extreme vertices of its bounding box, a rounding step short of
    it, or overlapping its bounds but not it: ``on_red_light`` is GEOS ``intersects`` for every one, so the bounds
    prune drops only boxes that cannot touch."""
    light = shapely.Polygon([(10.0, 0.0), (12.0, 2.0), (14.0, 0.0), (12.0, -2.0)])

    def box(xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
        # front left, rear left, rear right, front right (heading +x), then the centre
        corners = [(xmax, ymax), (xmin, ymax), (xmin, ymin), (xmax, ymin)]
        return np.array([*corners, ((xmin + xmax) / 2, (ymin + ymax) / 2)])

    # per side of the light's bounds, a box whose opposite side lies on it (touching the extreme vertex)
    beside = {
        "left": lambda edge: box(edge - 2.0, -1.0, edge, 1.0),
        "right": lambda edge: box(edge, -1.0, edge + 2.0, 1.0),
        "above": lambda edge: box(11.0, edge, 13.0, edge + 2.0),
        "below": lambda edge: box(11.0, edge - 2.0, 13.0, edge),
    }
    edges = {"left": 10.0, "right": 14.0, "above": 2.0, "below": -2.0}
    steps = (0.0, -np.inf, np.inf)  # on the bound, a rounding step either side
    boxes = [beside[side](np.nextafter(edge, step) if step else edge) for side, edge in edges.items() for step in steps]
    boxes.append(box(13.5, 1.5, 15.0, 3.0))  # inside the light's bounds, off the light
    coords = np.stack(boxes)[:, None]
    touching = on_red_light(coords, [[light]])[:, 0]
    expected = shapely.intersects(shapely.polygons(coords[:, 0, :4]), light)
    np.testing.assert_array_equal(touching, expected)
    assert 0 < expected.sum() < len(expected) - 1


def straight_centres(offset: np.ndarray) -> np.ndarray:
    return np.stack([np.arange(41) * 1.0, offset], -1)[None]


@pytest.mark.parametrize(("seconds", "expected"), [(2.5, 0.0), (1.5, 1.0), (2.0, 0.0), (1.9, 1.0)])
def test_lane_offset_of_0p7_m_fails_after_2_s(seconds: float, expected: float) -> None:
    centerline = shapely.linestrings([[-10.0, 0.0], [100.0, 0.0]])
    offset = np.where(np.arange(41) < round(seconds / 0.1), 0.7, 0.0)
    lk, failed_at = lane_keeping(straight_centres(offset), centerline, np.zeros((1, 41), bool))
    assert lk.tolist() == [expected]
    assert failed_at.tolist() == [19 if expected == 0.0 else -1]  # the 20th consecutive step (index 19)


def points_at_the_lane_limit(vertices: np.ndarray) -> np.ndarray:
    """Points at 0.5 m (as floats round it) from every segment's middle, both sides, and from every vertex along
    eight directions, each with its neighbours one rounding step either way in x and in y."""
    start, end = vertices[:-1], vertices[1:]
    along = end - start
    length = np.linalg.norm(along, axis=1, keepdims=True)
    normal = np.divide(along[:, ::-1] * [-1.0, 1.0], length, out=np.zeros_like(along), where=length > 0)
    middle = (start + end) / 2
    angles = np.arange(8) * np.pi / 4
    rays = np.stack([np.cos(angles), np.sin(angles)], -1)
    exact = np.concatenate(
        [
            middle + LANE_KEEPING_LIMIT_M * normal,
            middle - LANE_KEEPING_LIMIT_M * normal,
            (vertices[:, None] + LANE_KEEPING_LIMIT_M * rays).reshape(-1, 2),
        ]
    )
    step = np.stack([np.nextafter(exact, exact + 1.0) - exact, np.nextafter(exact, exact - 1.0) - exact])
    shifted = [exact + s * axis for s in step for axis in ([1.0, 0.0], [0.0, 1.0])]
    return np.concatenate([exact, *shifted])


@pytest.mark.parametrize("origin", [(0.0, 0.0), (664_432.25, 3_997_251.5)])  # a UTM-sized offset too
def test_lane_limit_equals_geos_distance_at_the_limit(origin: tuple[float, float]) -> None:
    rng = np.random.default_rng(0)
    # straight, diagonal and sharply turning segments, a repeated vertex, spacing 0.3-6 m
    local = np.array([[0, 0], [6, 0], [6.3, 0.1], [6.3, 0.1], [9, 3], [9.2, 3.4], [4, 7], [3.3, 7.05], [0.2, 2.9]])
    vertices = local + np.asarray(origin)
    centerline = shapely.linestrings(vertices)
    near = points_at_the_lane_limit(vertices)
    spread = vertices.min(axis=0) - 3 + rng.uniform(0, 1, (20_000, 2)) * (np.ptp(vertices, axis=0) + 6)
    far = vertices[0] + [[-1e3, 0.0], [0.0, 5e3]]  # outside the grid
    centres = np.concatenate([near, spread, far])
    geos = shapely.distance(shapely.points(centres), centerline) > LANE_KEEPING_LIMIT_M
    assert np.array_equal(beyond_lane_limit(centres[None], centerline)[0], geos)
    assert 0 < geos[: len(near)].sum() < len(near)  # the limit is reached from both sides
    assert geos[len(near) :].any() and not geos[len(near) :].all()


def test_intersection_steps_pause_the_lane_keeping_count() -> None:
    centerline = shapely.linestrings([[-10.0, 0.0], [100.0, 0.0]])
    offset = np.where(np.arange(41) < 25, 0.7, 0.0)
    paused = np.zeros((1, 41), bool)
    paused[0, 10:15] = True  # 10 + 10 counted steps: the count reaches 20 at step 24 without a reset
    assert lane_keeping(straight_centres(offset), centerline, paused)[1].tolist() == [24]
    paused[0, 10:16] = True  # only 19 counted offset steps remain
    assert lane_keeping(straight_centres(offset), centerline, paused)[0].tolist() == [1.0]
    on_line = offset.copy()
    on_line[12] = 0.0  # a step back within 0.5 m resets
    assert lane_keeping(straight_centres(on_line), centerline, np.zeros((1, 41), bool))[0].tolist() == [1.0]


def test_ddc_zeroes_intersection_displacement() -> None:
    centres = np.stack([np.arange(41) * 0.7, np.zeros(41)], -1)[None]  # 0.7 m per step, all of it oncoming
    oncoming = np.ones((1, 41), bool)
    assert driving_direction_compliance(centres, oncoming).tolist() == [0.0]  # 10 steps: 7 m >= 6 m
    inside = np.zeros((1, 41), bool)
    inside[0, ::2] = True  # even steps in an intersection: at most 6 odd steps per 11-sample window, 4.2 m
    assert driving_direction_compliance(centres, oncoming, exclude=inside).tolist() == [0.5]
    assert driving_direction_compliance(centres, oncoming, exclude=np.ones((1, 41), bool)).tolist() == [1.0]


@pytest.mark.parametrize(
    ("raw", "multiplier", "reference", "expected", "normaliser"),
    [
        ([40.0, 20.0], [1.0, 0.0], 0, [1.0, 0.5], [40.0, 40.0]),  # NC 0 does not mask the agent's own EP
        ([40.0, 50.0], [1.0, 0.5], 0, [1.0, 1.0], [40.0, 40.0]),  # clipped at 1
        ([4.0, 2.0], [1.0, 0.0], 0, [1.0, 1.0], [4.0, 4.0]),  # below 5 m everyone gets 1, NC 0 included
        ([40.0, 20.0, 10.0], [1.0, 1.0, 1.0], None, [1.0, 0.5, 0.25], [40.0] * 3),
    ],
)
def test_v2_progress_is_unmasked(raw, multiplier, reference, expected, normaliser) -> None:
    ep, norm = ego_progress_v2(np.array(raw), np.array(multiplier), reference)
    assert ep.tolist() == expected and norm.tolist() == normaliser


def test_center_frame_adds_the_rotation_terms_to_the_longitudinal_acceleration() -> None:
    states = np.zeros((1, 1, 11))
    states[..., StateIndex.ACCELERATION_X], states[..., StateIndex.ACCELERATION_Y] = 1.0, 0.3
    states[..., StateIndex.ANGULAR_VELOCITY], states[..., StateIndex.ANGULAR_ACCELERATION] = 0.5, 0.2
    center = center_frame(states, PACIFICA)
    assert center[0, 0, StateIndex.ACCELERATION_X] == pytest.approx(1.0 + 1.461 * (0.25 + 0.2), abs=1e-12)
    assert center[0, 0, StateIndex.ACCELERATION_Y] == 0.3


def logged_past(ax: float) -> np.ndarray:
    """t, x, y, heading, vx, vy, ax, ay at -1.5, -1.0, -0.5, 0 s; the ego at 10 m/s at t0."""
    t = np.array([-1.5, -1.0, -0.5, 0.0])
    return np.stack([t, 10.0 * t, 0 * t, 0 * t, 10.0 - ax * t, 0 * t, np.array([ax, ax, ax, 0.0]), 0 * t], -1)


def test_past_is_sampled_every_0p1_s_without_its_last_two_samples() -> None:
    past = past_states(logged_past(-6.0))
    assert len(past) == 14  # -1.5 .. -0.2 s
    assert past[:, StateIndex.X] == pytest.approx(10.0 * np.arange(-1.5, -0.15, 0.1), abs=1e-9)
    assert past[:, StateIndex.ACCELERATION_X][-3:] == pytest.approx([-4.8, -3.6, -2.4], abs=1e-9)  # -0.4 .. -0.2 s
    assert (past[:, StateIndex.ANGULAR_VELOCITY] == 0).all()


def test_hard_braking_in_the_past_fails_history_comfort() -> None:
    cruising = drive(10.0 * TIMES, speed=np.full(41, 10.0))
    assert history_comfort(cruising, logged_past(0.0), PACIFICA).tolist() == [1.0]
    assert history_comfort(cruising, logged_past(-6.0), PACIFICA).tolist() == [0.0]  # -6 < -4.05 m/s^2
    assert history_comfort(cruising, None, PACIFICA).tolist() == [1.0]  # no past: HC is 1


def test_log_replay_removes_tracks_overlapping_the_ego_at_t0() -> None:
    poses = np.array([[1.0, 0.5, 0.3], [1.0, 3.5, 0.0], [-5.0, 0.0, 0.0]])  # on the ego / one lane left / behind
    size = np.array([[4.8, 2.0, 1.6]] * 3)
    present = np.array([True, True, False])
    assert overlapping_ego_at_t0(poses, present, size, PACIFICA).tolist() == [True, False, False]
    scene = road_scene([agent(BoxClass.VEHICLE, 1.0, 0.0), agent(BoxClass.VEHICLE, 30.0, 0.0)])
    replay = log_observation(scene, V2_STEPS, replay=True)
    assert replay.objects.tolist() == [1] * V2_STEPS  # only the car ahead is left, at every step
    assert v2(scene, drive(np.zeros(41)))[epdms.NC][0] == 1.0


def scene_with_human(human_speed: float) -> PDMScene:
    scene = road_scene()
    return dataclasses.replace(
        scene,
        ego_velocity=np.array([10.0, 0.0]),
        human_poses=cruise(human_speed),
        ego_past=logged_past(0.0),
    )


def test_ec_nan_without_a_previous_frame_drops_its_weight() -> None:
    scene = scene_with_human(10.0)
    proposals = np.stack([cruise(10.0), cruise(7.0)])
    scores = score_proposals(scene, proposals, 0.5, reference=reference_at(10.0), metric=EPDMS_METRIC)
    assert np.isnan(scores[epdms.EC]).all()
    ep = scores[epdms.EP]
    assert 0.6 < ep[1] < 0.8 and ep[0] == pytest.approx(1.0, abs=1e-3)
    weighted = 5 * ep + 5 * scores[epdms.TTC] + 2 * scores[epdms.LK] + 2 * scores[epdms.HC]
    assert scores["score"] == pytest.approx(weighted / 14, abs=1e-12)


def reference_at(speed: float) -> np.ndarray:
    t = np.arange(51) * 0.1
    return np.stack([speed * t, 0 * t, 0 * t], -1)


def test_ec_compares_with_the_plan_made_half_a_second_earlier() -> None:
    scene = scene_with_human(10.0)
    earlier = dict(
        ego_pose=np.array([-5.0, 0.0, 0.0]), ego_velocity=np.array([10.0, 0.0]), ego_acceleration=np.zeros(2)
    )
    consistent = PreviousFrame(**earlier, poses=cruise(10.0), interval=0.5)
    braking = PreviousFrame(
        **earlier, poses=np.stack([np.minimum(cruise(10.0)[:, 0], 8.0), *np.zeros((2, 8))], -1), interval=0.5
    )
    proposals = np.stack([cruise(10.0)] * 3)
    scores = score_proposals(
        scene, proposals, 0.5, reference_at(10.0), metric=EPDMS_METRIC, previous=[consistent, braking, None]
    )
    assert scores[epdms.EC][:2].tolist() == [1.0, 0.0] and np.isnan(scores[epdms.EC][2])
    assert scores["score"][:2] == pytest.approx([1.0, 14 / 16], abs=1e-9)
    assert scores["score"][2] == pytest.approx(1.0, abs=1e-9)
    with pytest.raises(ValueError, match="one per proposal"):
        score_proposals(scene, proposals, 0.5, reference_at(10.0), metric=EPDMS_METRIC, previous=[None])
    with pytest.raises(ValueError, match="EC"):
        score_proposals(scene, proposals, 0.5, reference_at(10.0), previous=[None] * 3)
