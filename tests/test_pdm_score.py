"""PDMS v1.1 scoring layer: the official golden cases, then hand-built scenes with hand-worked numbers."""

import numpy as np
import pytest
import shapely
from pdm_golden import agent_states_10hz, golden_scene, load_golden, reference_poses, simulated_states
from pdm_scenes import KEYFRAMES, ROAD, TIMES, agent, drive, road_scene

from lead_s2r.schema import BoxClass, MapKind
from lead_s2r.scoring.pdm.comfort import comfort, phase_unwrap
from lead_s2r.scoring.pdm.map_flags import DrivableMap
from lead_s2r.scoring.pdm.metrics import driving_direction_compliance, ego_progress, pdms_v11
from lead_s2r.scoring.pdm.observation import dense_observation, interpolate_keyframes, log_observation
from lead_s2r.scoring.pdm.scene import PDMScene
from lead_s2r.scoring.pdm.score import COLUMNS, score_proposals, score_states

GOLDEN = load_golden()
CASES = {case["id"]: case for case in GOLDEN["scenes"]}
SUB_SCORES = {
    "NC": "no_at_fault_collisions",
    "DAC": "drivable_area_compliance",
    "DDC": "driving_direction_compliance",
    "TTC": "time_to_collision_within_bound",
    "C": "comfort",
}
FLAGS = ("multiple_lanes", "non_drivable_area", "oncoming_traffic")


def _idx(value: int | None) -> int:
    return -1 if value is None else value


def _flag_string(flags: np.ndarray) -> str:
    return "".join("1" if f else "0" for f in flags)


def _check_row(scores: dict[str, np.ndarray], row: int, official: dict) -> None:
    for name, column in SUB_SCORES.items():
        assert scores[column][row] == official[name], name
    assert scores["progress_m"][row] == pytest.approx(official["progress_m"], abs=2e-6)
    assert scores["collision_time_idx"][row] == _idx(official["collision_time_idx"])
    assert scores["ttc_time_idx"][row] == _idx(official["ttc_time_idx"])
    for flag in FLAGS:
        assert _flag_string(scores[flag][row]) == official["flags"][flag], flag


@pytest.mark.parametrize("case_id", list(CASES))
def test_golden_simulated_states_score_as_official(case_id: str) -> None:
    """Reference and every trajectory of a scene in one call, each EP normalised over [reference, itself]."""
    case = CASES[case_id]
    scene = golden_scene(case)
    scores = score_states(scene, simulated_states(case), log_observation(scene), ep_reference=0)
    _check_row(scores, 0, case["reference_trajectory"]["official"])
    for row, trajectory in enumerate(case["trajectories"], start=1):
        official = trajectory["official"]
        _check_row(scores, row, official)
        assert scores["ego_progress"][row] == pytest.approx(official["EP"], abs=1e-6)
        assert scores["score"][row] == pytest.approx(official["PDMS"], abs=1e-6)
        assert scores["ep_normaliser_m"][row] == pytest.approx(official["ep_normaliser_m"], abs=2e-6)


def test_golden_pair_normalised_together_matches_reference_ep() -> None:
    """ep_reference=None on [reference, agent] is one official call: both EPs come out as NAVSIM reported them."""
    case = CASES["S03_rear_end_stopped_car"]
    scene, states = golden_scene(case), simulated_states(case)
    for row, trajectory in enumerate(case["trajectories"], start=1):
        scores = score_states(scene, states[[0, row]], log_observation(scene), ep_reference=None)
        assert scores["ego_progress"][1] == pytest.approx(trajectory["official"]["EP"], abs=1e-6)
        assert scores["ego_progress"][0] == pytest.approx(trajectory["official"]["reference_EP_in_this_call"], abs=1e-6)


@pytest.mark.parametrize("case_id", [c for c in CASES if CASES[c]["agents"]])
def test_golden_observation_interpolation(case_id: str) -> None:
    case = CASES[case_id]
    scene = golden_scene(case)
    expected, present = agent_states_10hz(case)
    is_agent = np.isin(scene.agent_class, [BoxClass.VEHICLE])
    poses, velocity, valid = interpolate_keyframes(
        scene.agent_t, scene.agent_poses, scene.agent_velocity, scene.agent_valid, is_agent
    )
    np.testing.assert_array_equal(valid, present)
    np.testing.assert_allclose(poses[valid][:, :2], expected[valid][:, :2], atol=1e-5)
    np.testing.assert_allclose(np.cos(poses[valid][:, 2] - expected[valid][:, 2]), 1.0, atol=1e-10)
    np.testing.assert_allclose(velocity[valid], expected[valid][:, 3:], atol=1e-5)


def test_score_proposals_reproduces_official_scores() -> None:
    """Interpolation, simulation and scoring end to end: the official sub-scores, EP and PDMS of every trajectory."""
    pytest.importorskip("lead_s2r.scoring.pdm.interpolation")
    pytest.importorskip("lead_s2r.scoring.pdm.simulation")
    for case in GOLDEN["scenes"]:
        scene = golden_scene(case)
        proposals = np.array([t["poses"] for t in case["trajectories"]], np.float64)
        (interval,) = {t["interval_s"] for t in case["trajectories"]}
        scores = score_proposals(scene, proposals, interval, reference=reference_poses(case))
        assert set(scores) == set(COLUMNS)
        for row, trajectory in enumerate(case["trajectories"]):
            official = trajectory["official"]
            for name, column in SUB_SCORES.items():
                assert scores[column][row] == official[name], (trajectory["id"], name)
            assert scores["ego_progress"][row] == pytest.approx(official["EP"], abs=1e-6)
            assert scores["score"][row] == pytest.approx(official["PDMS"], abs=1e-6), trajectory["id"]
            assert scores["progress_m"][row] == pytest.approx(official["progress_m"], abs=2e-6)
            assert scores["ep_normaliser_m"][row] == pytest.approx(official["ep_normaliser_m"], abs=2e-6)
            assert scores["collision_time_idx"][row] == _idx(official["collision_time_idx"])
            assert scores["ttc_time_idx"][row] == _idx(official["ttc_time_idx"])


def score(scene: PDMScene, *rows: np.ndarray, reference: int | None = None) -> dict[str, np.ndarray]:
    return score_states(scene, np.concatenate(rows), log_observation(scene), ep_reference=reference)


def test_stationary_ego_hit_by_a_moving_car_is_not_at_fault() -> None:
    """A car 8 m ahead backs into the ego at 2 m/s: the standing ego is not at fault; rolling forward it would be."""
    scene = road_scene([agent(BoxClass.VEHICLE, 8.0, 0.0, vx=-2.0)])
    standing = drive(np.zeros(41))
    rolling = drive(0.5 * TIMES)
    scores = score(scene, standing, rolling)
    assert scores["no_at_fault_collisions"].tolist() == [1.0, 0.0]
    assert scores["collision_time_idx"][0] == -1
    assert scores["time_to_collision_within_bound"][0] == 1.0  # TTC skips a standing ego
    assert scores["score"][0] == 1.0  # neither row moves 5 m: EP 1 where NC * DAC > 0


def test_rear_end_into_a_stopped_car() -> None:
    """Ego at 10 m/s, stopped car centred 20 m ahead (rear at 17.6 m); ego front = x + 4.049. Contact at
    t = 1.3551 s -> first step 14; TTC's 0.9 s look-ahead first reaches it at t = 0.5 s -> step 5."""
    scene = road_scene([agent(BoxClass.VEHICLE, 20.0, 0.0)])
    scores = score(scene, drive(10.0 * TIMES))
    assert scores["no_at_fault_collisions"][0] == 0.0
    assert scores["collision_time_idx"][0] == 14
    assert scores["ttc_time_idx"][0] == 5
    assert scores["ego_progress"][0] == 0.0
    assert scores["score"][0] == 0.0


def test_cone_hit_scores_half() -> None:
    scene = road_scene([agent(BoxClass.TRAFFIC_CONE, 20.0, 0.5, size=(0.5, 0.5, 1.0))])
    scores = score(scene, drive(8.0 * TIMES))
    assert scores["no_at_fault_collisions"][0] == 0.5
    nc, ttc, c = 0.5, scores["time_to_collision_within_bound"][0], scores["comfort"][0]
    assert ttc == 0.0 and c == 1.0
    assert scores["ego_progress"][0] == 1.0  # alone in its group: masked progress 16 m normalised by itself
    assert scores["score"][0] == pytest.approx(nc * (5 * 1.0 + 5 * ttc + 2 * c) / 12)


def test_leaving_the_road() -> None:
    """Drifting right at 1 m/s while doing 10 m/s (heading h = atan2(-1, 10)): the front-right corner lies
    4.049 sin h - 1.1485 cos h = -1.546 m from the rear axle in y, so it leaves roadblock 1 (y < -1.75) after
    0.204 s: from step 3 on."""
    scene = road_scene()
    scores = score(scene, drive(10.0 * TIMES, -1.0 * TIMES))
    assert scores["drivable_area_compliance"][0] == 0.0
    assert np.flatnonzero(~scores["non_drivable_area"][0]).tolist() == [0, 1, 2]
    assert scores["ego_progress"][0] == 0.0 and scores["score"][0] == 0.0


@pytest.mark.parametrize(("speed", "expected"), [(3.0, 0.5), (7.0, 0.0)])
def test_driving_against_traffic(speed: float, expected: float) -> None:
    """In the oncoming lane (y = 7) for the whole horizon, 1 s covers `speed` metres: 3 m -> 0.5, 7 m -> 0. With the
    lane on the route DDC is 1, and the PDMS is the same (DDC weighs 0 in v1.1)."""
    path = drive(speed * TIMES, 7.0)
    against = score(road_scene(), path)
    along = score(road_scene(route=(11, 12, 21)), path)
    assert against["oncoming_traffic"][0].all()
    assert against["driving_direction_compliance"][0] == expected
    assert along["driving_direction_compliance"][0] == 1.0
    assert against["score"][0] == along["score"][0] == 1.0


def test_ddc_window_sums_one_second() -> None:
    """Oncoming for 4 consecutive 1.0 m steps only: the 1 s window holds 4 m -> 0.5; excluded steps do not count."""
    centers = np.stack([np.arange(41.0), np.zeros(41)], -1)[None]
    oncoming = np.zeros((1, 41), bool)
    oncoming[0, 10:14] = True
    assert driving_direction_compliance(centers, oncoming)[0] == 0.5
    oncoming[0, 10:17] = True
    assert driving_direction_compliance(centers, oncoming)[0] == 0.0
    assert driving_direction_compliance(centers, oncoming, exclude=oncoming)[0] == 1.0


def test_hard_brake_is_uncomfortable() -> None:
    """15 m/s braking at 6 m/s^2 (beyond -4.05) is uncomfortable; at 2 m/s^2 it is not."""
    hard = np.maximum(15.0 - 6.0 * TIMES, 0.0)
    gentle = 15.0 - 2.0 * TIMES
    rows = [drive(np.concatenate([[0.0], np.cumsum(v[:-1] * 0.1)]), speed=v) for v in (hard, gentle)]
    assert comfort(np.concatenate(rows)).tolist() == [0.0, 1.0]


def test_phase_unwrap_rounds_jumps() -> None:
    unwrapped = phase_unwrap(np.array([3.1, -3.1, -2.9]))
    np.testing.assert_allclose(unwrapped, [3.1, 2 * np.pi - 3.1, 2 * np.pi - 2.9])


@pytest.mark.parametrize(
    ("raw", "multiplier", "reference", "expected", "normaliser"),
    [
        ([4.9, 3.0], [1.0, 1.0], 0, [1.0, 1.0], [4.9, 4.9]),  # best <= 5 m: everyone 1
        ([4.9, 3.0], [1.0, 0.0], 0, [1.0, 0.0], [4.9, 4.9]),  # ... except where NC * DAC = 0
        ([6.0, 3.0], [1.0, 1.0], 0, [1.0, 0.5], [6.0, 6.0]),  # best > 5 m: divide by it
        ([6.0, 9.0, 3.0], [1.0, 1.0, 1.0], 0, [1.0, 1.0, 0.5], [6.0, 9.0, 6.0]),  # pairs [0, row]
        ([6.0, 9.0, 3.0], [1.0, 1.0, 1.0], None, [6 / 9, 1.0, 1 / 3], [9.0, 9.0, 9.0]),  # one group
        ([6.0, 9.0], [1.0, 0.5], 0, [1.0, 0.75], [6.0, 6.0]),  # masked: 9 m * 0.5 = 4.5 m
    ],
)
def test_progress_normalisation(raw, multiplier, reference, expected, normaliser) -> None:
    ep, norm = ego_progress(np.array(raw), np.array(multiplier), reference)
    np.testing.assert_allclose(ep, expected)
    np.testing.assert_allclose(norm, normaliser)


def test_progress_threshold_in_a_scene() -> None:
    """Reference 4 m, agent 2 m: under the 5 m threshold both get EP 1. Reference 12 m, agent 6 m: EP 0.5."""
    short = score(road_scene(), drive(1.0 * TIMES), drive(0.5 * TIMES), reference=0)
    np.testing.assert_allclose(short["progress_m"], [4.0, 2.0])
    assert short["ego_progress"].tolist() == [1.0, 1.0]
    long = score(road_scene(), drive(3.0 * TIMES), drive(1.5 * TIMES), reference=0)
    np.testing.assert_allclose(long["ego_progress"], [1.0, 0.5])


def test_aggregation_weights() -> None:
    score_ = pdms_v11(*(np.array([v]) for v in (1.0, 1.0, 0.5, 1.0, 0.0, 0.0)))
    assert score_[0] == pytest.approx((5 * 0.5 + 5 * 1.0 + 2 * 0.0) / 12)


def test_track_seen_once_and_interpolation() -> None:
    """Track 0 seen only at keyframe 3: present, unchanged, at all 51 steps. Track 1 seen at keyframes 2 and 4 with
    headings 3.1 and -3.1: present for t in [1, 2] s only, interpolated through pi. Track 2 is a cone: no velocity."""
    poses = np.zeros((3, 11, 3))
    velocity = np.ones((3, 11, 2))
    valid = np.zeros((3, 11), bool)
    valid[0, 3] = True
    poses[0, 3] = [5.0, 1.0, 0.3]
    valid[1, [2, 4]] = True
    poses[1, 2], poses[1, 4] = [0.0, 0.0, 3.1], [10.0, 2.0, -3.1]
    valid[2, :] = True
    out_poses, out_velocity, out_valid = interpolate_keyframes(
        KEYFRAMES, poses, velocity, valid, np.array([True, True, False])
    )
    assert out_valid[0].all() and (out_poses[0] == [5.0, 1.0, 0.3]).all()
    assert np.flatnonzero(out_valid[1]).tolist() == list(range(10, 21))
    np.testing.assert_allclose(out_poses[1, 15, :2], [5.0, 1.0])
    assert abs(out_poses[1, 15, 2]) == pytest.approx(np.pi)
    assert (out_velocity[2] == 0.0).all()


def test_track_seen_once_collides_everywhere() -> None:
    """A stopped car seen at one keyframe only still blocks the lane at every step."""
    car = agent(BoxClass.VEHICLE, 20.0, 0.0)
    car["valid"] = np.arange(11) == 6
    scores = score(road_scene([car]), drive(10.0 * TIMES))
    assert scores["collision_time_idx"][0] == 14


def test_nan_states_and_poses_name_the_scene() -> None:
    scene = road_scene()
    states = drive(TIMES)
    states[0, 3, 0] = np.nan
    with pytest.raises(ValueError, match="hand-built"):
        score_states(scene, states, log_observation(scene), ep_reference=None)
    with pytest.raises(ValueError, match=r"hand-built.*NaN"):
        score_proposals(scene, np.full((2, 8, 3), np.nan), 0.5, reference=np.zeros((51, 3)))


def test_many_rows_score_like_one() -> None:
    """Scoring rows together gives each row what it gets alone (EP per [reference, row] pair)."""
    scene = road_scene([agent(BoxClass.VEHICLE, 30.0, 0.0, vx=4.0)])
    rows = [drive(v * TIMES) for v in (8.0, 5.0, 10.0, 2.0)]
    together = score(scene, *rows, reference=0)
    for i in range(1, len(rows)):
        alone = score(scene, rows[0], rows[i], reference=0)
        for column in COLUMNS:
            assert together[column][i] == alone[column][1], column


def test_drivable_map_ignores_roadblock_connectors_and_walkways() -> None:
    scene = road_scene()
    scene.polygon_kind = scene.polygon_kind.copy()
    scene.polygon_kind[0] = MapKind.ROADBLOCK_CONNECTOR
    assert len(DrivableMap.from_scene(scene).polygons) == len(ROAD) - 1
    scores = score(scene, drive(10.0 * TIMES))
    assert scores["drivable_area_compliance"][0] == 0.0  # lanes alone are not drivable area


def test_dense_observation_red_lights_never_count() -> None:
    """PDM-Closed's forecasts: a red-light polygon across the lane is skipped by NC and TTC; a stopped car beyond it
    is a collision."""
    scene = road_scene()
    poses = np.zeros((1, 51, 3))
    poses[0, :, 0] = 20.0
    boxes = dict(velocity=np.zeros((1, 51, 2)), size=[[4.8, 2.0, 1.6]], agent_class=[BoxClass.VEHICLE])
    red = [[shapely.box(10.0, -1.75, 12.0, 1.75)]] * 51
    path = drive(10.0 * TIMES)
    for car, expected in ((False, 1.0), (True, 0.0)):
        observation = dense_observation(poses, valid=np.full((1, 51), car), red_light_polygons=red, **boxes)
        scores = score_states(scene, path, observation, ep_reference=None)
        assert scores["no_at_fault_collisions"][0] == expected
        assert scores["time_to_collision_within_bound"][0] == expected
    assert np.diff(observation.step_offsets).tolist() == [2] * 51  # the light and the car at every step


def test_log_observation_reads_keyframes_up_to_its_horizon() -> None:
    """Seen at 2.0 s and 4.5 s: bridged over 2.0..4.5 s with v1.1's 5 s horizon; within v2's 4 s (41 steps) it is
    seen once, so it stands at its 2.0 s pose at every step."""
    car = agent(BoxClass.VEHICLE, 20.0, 0.0, vx=2.0)
    car["valid"] = np.isin(np.arange(11), [4, 9])
    scene = road_scene([car])
    v11, v2 = log_observation(scene), log_observation(scene, num_steps=41)
    assert np.diff(v11.step_offsets).tolist() == [0] * 20 + [1] * 26 + [0] * 5
    assert np.diff(v2.step_offsets).tolist() == [1] * 41
    np.testing.assert_allclose(v2.centroids, np.tile([24.0, 0.0], (41, 1)), atol=1e-12)
