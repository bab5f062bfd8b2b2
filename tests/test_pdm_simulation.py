"""PDM interpolation and simulation: every trajectory of the official v1.1 and v2.2 golden files, and hand cases.

The golden scenes are in a global frame: inputs move to the ego frame at ``ego_initial`` (rear axle) and our
results move back to the global frame for the comparison (headings compared wrapped). Golden arrays are rounded to
1e-6, so 1e-6 leaves our own error 5e-7.
"""

import gzip
import json
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lead_s2r.scoring.pdm.interpolation import interpolate_proposals, interpolate_reference, sample_times_us
from lead_s2r.scoring.pdm.lqr import (
    CURVATURE_RATE_PENALTY,
    INITIAL_CURVATURE_PENALTY,
    JERK_PENALTY,
    curvature_profile,
    normalize_angle,
    speed_fit_matrix,
    track,
    tracking_reference,
)
from lead_s2r.scoring.pdm.simulation import simulate_proposals
from lead_s2r.scoring.pdm.state import StateIndex

DATA = Path(__file__).parent / "data"
GOLDEN_FILES = ("navsim_pdms_v11_official.json.gz", "navsim_epdms_v22_official.json.gz")
TOLERANCE = 1e-6
# a real NAVSIM timestamp (us): at ~1.6e9 s float64 seconds are ~2.4e-7 s apart, so nuPlan's truncation bites
T0_US = 1624385736449714


@cache
def golden(name: str) -> dict[str, Any]:
    with gzip.open(DATA / name, "rt") as handle:
        return json.load(handle)


def golden_scenes() -> list[tuple[str, str]]:
    return [(name, scene["id"]) for name in GOLDEN_FILES for scene in golden(name)["scenes"]]


def to_ego(poses: np.ndarray, ego: dict[str, float]) -> np.ndarray:
    cos, sin = np.cos(ego["heading"]), np.sin(ego["heading"])
    dx, dy = poses[:, 0] - ego["x"], poses[:, 1] - ego["y"]
    return np.stack([cos * dx + sin * dy, -sin * dx + cos * dy, poses[:, 2] - ego["heading"]], axis=-1)


def to_global(poses: np.ndarray, ego: dict[str, float]) -> np.ndarray:
    cos, sin = np.cos(ego["heading"]), np.sin(ego["heading"])
    out = np.array(poses)
    out[..., 0] = ego["x"] + cos * poses[..., 0] - sin * poses[..., 1]
    out[..., 1] = ego["y"] + sin * poses[..., 0] + cos * poses[..., 1]
    out[..., 2] = poses[..., 2] + ego["heading"]
    return out


def max_error(ours: np.ndarray, official: list) -> float:
    official = np.asarray(official)
    error = np.abs(ours - official)
    error[..., 2] = np.abs((ours[..., 2] - official[..., 2] + np.pi) % (2 * np.pi) - np.pi)
    return float(error.max())


def frames(scene: dict[str, Any]) -> list[dict[str, Any]]:
    """Each ego frame of a scene with its cases (ego-frame input poses, interval or None for the 0.1 s reference,
    official block). v2.2 adds the human trajectory and previous frames (their own ego, 0.5 s earlier)."""
    ego = scene["ego_initial"]
    reference = scene["reference_trajectory"]
    cases = [("reference", to_ego(np.array(reference["poses"]), ego), None, reference["official"])]
    human = scene.get("human_trajectory")
    if human and "target_states" in human.get("official", {}):
        cases.append(("human", np.array(human["poses"]), human["interval_s"], human["official"]))
    cases += [(t["id"], np.array(t["poses"]), t["interval_s"], t["official"]) for t in scene["trajectories"]]
    out = [{"ego": ego, "t0_us": scene["t0_us"], "cases": cases}]
    for trajectory in scene["trajectories"]:
        previous = trajectory.get("previous_frame")
        if previous:
            case = (trajectory["id"] + "/previous", np.array(previous["poses"]), previous["interval_s"])
            out.append(
                {
                    "ego": previous["ego_state"],
                    "t0_us": scene["t0_us"] - 500_000,
                    "cases": [(*case, previous["official"])],
                }
            )
    return out


@pytest.mark.parametrize(("name", "scene_id"), golden_scenes())
def test_golden_targets_and_simulation(name: str, scene_id: str) -> None:
    scene = next(s for s in golden(name)["scenes"] if s["id"] == scene_id)
    for frame in frames(scene):
        ego, t0_us = frame["ego"], frame["t0_us"]
        targets = []
        for case_id, poses, interval, official in frame["cases"]:
            if interval is None:
                ours = interpolate_reference(poses, t0_us=t0_us)
            else:
                ours = interpolate_proposals(poses[None], interval, t0_us=t0_us)[0]
            assert max_error(to_global(ours, ego), official["target_states"]) <= TOLERANCE, case_id
            targets.append(ours)
        simulated = simulate_proposals(
            np.stack(targets),  # all cases of a frame in one batch, as NAVSIM batches reference and agent
            np.array([ego["vx"], ego["vy"]]),
            np.array([ego["ax"], ego["ay"]]),
            ego.get("tire_steering_angle", 0.0),
        )
        for (case_id, *_, official), states in zip(frame["cases"], simulated, strict=True):
            states = np.concatenate([to_global(states[:, :3], ego), states[:, 3:]], axis=1)
            assert max_error(states, official["simulated_states"]) <= TOLERANCE, case_id


def straight(speed: float, interval: float = 0.5, count: int = 8) -> np.ndarray:
    """Poses ``(1, count, 3)`` straight ahead at constant speed."""
    t = interval * np.arange(1, count + 1)
    return np.stack([speed * t, np.zeros_like(t), np.zeros_like(t)], axis=-1)[None]


def arc(radius: float, speed: float) -> np.ndarray:
    """Poses ``(1, 8, 3)`` every 0.5 s on a left circle of ``radius`` through the ego, at constant speed."""
    theta = speed * 0.5 * np.arange(1, 9) / radius
    return np.stack([radius * np.sin(theta), radius * (1 - np.cos(theta)), theta], axis=-1)[None]


def test_interpolation_is_linear_in_time_and_holds_the_last_pose() -> None:
    targets = interpolate_proposals(straight(10.0), 0.5)[0]
    np.testing.assert_allclose(targets[:, 0], np.arange(41), atol=1e-12)  # 10 m/s -> 1 m per 0.1 s
    short = interpolate_proposals(straight(10.0, interval=0.5, count=2), 0.5)[0]
    np.testing.assert_allclose(short[:11, 0], np.arange(11), atol=1e-12)
    np.testing.assert_array_equal(short[10:], np.tile([10.0, 0.0, 0.0], (31, 1)))  # t >= 1 s holds the last pose


def test_interpolation_turns_the_short_way_through_pi() -> None:
    poses = np.array([[[0.0, 0.0, 3.0], [0.0, 0.0, -3.0]]])  # +3 rad then -3 rad: 0.28 rad apart through pi
    heading = interpolate_proposals(poses, 0.5)[0, :, 2]
    assert heading[2] == pytest.approx(1.2)  # t = 0.2 s: 0 -> 3 rad
    assert heading[5] == pytest.approx(3.0)
    step = (2 * np.pi - 6.0) / 5  # 0.28 rad over 0.5 s
    assert heading[7] == pytest.approx(3.0 + 2 * step)  # t = 0.7 s, still below pi
    assert heading[8] == pytest.approx(3.0 + 3 * step - 2 * np.pi)  # t = 0.8 s, past pi: wrapped to [-pi, pi)
    assert heading[10] == pytest.approx(-3.0)


def test_interpolation_reproduces_nuplans_microsecond_truncation() -> None:
    times = sample_times_us(T0_US)
    assert list(times[:7]) == [0, 99_999, 200_000, 300_000, 400_000, 500_000, 599_999]
    targets = interpolate_proposals(straight(10.0), 0.5, t0_us=T0_US)[0]
    assert targets[1, 0] == pytest.approx(0.99999, abs=1e-12)  # 1 us early at 10 m/s
    assert targets[2, 0] == pytest.approx(2.0, abs=1e-12)


def test_reference_keeps_its_first_41_poses() -> None:
    reference = np.stack([np.arange(51) * 0.8, np.linspace(0, 1, 51), np.linspace(0, 0.2, 51)], axis=-1)
    np.testing.assert_allclose(interpolate_reference(reference), reference[:41], atol=1e-12)


def test_bad_shapes_are_errors_naming_the_argument() -> None:
    with pytest.raises(ValueError, match="proposals"):
        interpolate_proposals(np.zeros((8, 3)), 0.5)
    with pytest.raises(ValueError, match="reference"):
        interpolate_reference(np.zeros((1, 3)))
    nan = interpolate_proposals(straight(10.0), 0.5)[:, :8].copy()
    nan[0, 3, 1] = np.nan
    with pytest.raises(ValueError, match=r"proposals: NaN .* \[\[0, 3\]\]"):
        interpolate_proposals(nan, 0.5)
    with pytest.raises(ValueError, match="targets"):
        simulate_proposals(np.zeros((41, 3)), np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match="ego_velocity"):
        simulate_proposals(np.zeros((1, 41, 3)), np.array(10.0), np.zeros(2))


def test_initial_state_is_the_logged_ego() -> None:
    states = simulate_proposals(interpolate_proposals(straight(10.0), 0.5), np.array([9.0, 0.3]), np.array([1.0, 0.2]))
    np.testing.assert_array_equal(states[0, 0], [0, 0, 0, 9.0, 0.3, 1.0, 0.2, 0, 0, 0, 0])
    assert states[0, 1, StateIndex.VELOCITY_Y] == 0.0 and states[0, 1, StateIndex.ACCELERATION_Y] == 0.0
    assert states[0, 1, StateIndex.X] == pytest.approx(9.0 * 0.1)  # the first step moves at the logged speed


def test_bicycle_keeps_its_heading_on_a_straight() -> None:
    for speed, target_speed in ((10.0, 10.0), (5.0, 12.0), (12.0, 0.0)):
        states = simulate_proposals(
            interpolate_proposals(straight(target_speed), 0.5), np.array([speed, 0]), np.zeros(2)
        )
        assert np.all(
            states[0, :, [StateIndex.Y, StateIndex.HEADING, StateIndex.STEERING_ANGLE, StateIndex.ANGULAR_VELOCITY]]
            == 0.0
        )


def test_tracks_a_gentle_curve_within_30_cm() -> None:
    for radius, steering in ((200.0, 0.0), (100.0, np.arctan(3.089 / 100.0))):  # from NAVSIM's steering 0, or steady
        targets = interpolate_proposals(arc(radius, 10.0), 0.5)
        states = simulate_proposals(targets, np.array([10.0, 0.0]), np.zeros(2), steering)
        assert np.hypot(*(states[0, :, :2] - targets[0, :, :2]).T).max() <= 0.3
        assert np.abs(states[0, :, StateIndex.VELOCITY_X] - 10.0).max() < 0.01
        assert states[0, -1, StateIndex.HEADING] == pytest.approx(40.0 / radius, abs=0.01)


def test_stopping_controller_takes_over_at_or_below_20_cm_per_s() -> None:
    at_rest = interpolate_proposals(np.zeros((1, 8, 3)), 0.5)
    # P controller: 0.5 * (0 - 0.2) = -0.1 m/s^2, through the 0.2 s lag: -0.1 * 0.1 / 0.3
    stopping = simulate_proposals(at_rest, np.array([0.2, 0.0]), np.zeros(2))
    assert stopping[0, 1, StateIndex.ACCELERATION_X] == pytest.approx(-0.1 / 3)
    # above it the longitudinal LQR: -10 / 11 * (0.21 - 0), lagged
    tracking = simulate_proposals(at_rest, np.array([0.21, 0.0]), np.zeros(2))
    assert tracking[0, 1, StateIndex.ACCELERATION_X] == pytest.approx(-10 / 11 * 0.21 / 3)
    # a target 1 m to the left at rest: the stopping controller never steers, the LQR does
    aside = interpolate_proposals(np.tile([0.0, 1.0, 0.0], (1, 8, 1)), 0.5)
    assert np.all(simulate_proposals(aside, np.array([0.15, 0.0]), np.zeros(2))[0, :, StateIndex.STEERING_ANGLE] == 0.0)
    assert simulate_proposals(aside, np.array([0.25, 0.0]), np.zeros(2))[0, 2, StateIndex.STEERING_ANGLE] > 0.0


def test_proposals_are_simulated_independently() -> None:
    """A proposal's states are the same bits alone as among others (a vocabulary entry scored alone)."""
    batch = np.concatenate([straight(10.0), arc(100.0, 8.0), np.zeros((1, 8, 3)), arc(-30.0, 4.0)])
    targets = interpolate_proposals(batch, 0.5)
    velocity, acceleration = np.array([9.0, 0.0]), np.array([-0.5, 0.0])
    together = simulate_proposals(targets, velocity, acceleration)
    for index in range(len(batch)):
        alone = simulate_proposals(targets[index : index + 1], velocity, acceleration)
        assert together[index].tobytes() == alone[0].tobytes()


def test_speed_fit_is_the_regularised_least_squares_of_its_definition() -> None:
    """Displacement i = dt v_i along the target heading, v_i = v_0 + dt sum_{j<i} a_j; penalty 1e-4 on -a_r for
    r < M - 2 and on a_{M-2} - a_{M-3} (nuPlan's overwritten difference matrix)."""
    rng = np.random.default_rng(0)
    m, dt = 40, 0.1
    headings = rng.uniform(-np.pi, np.pi, m)
    displacements = rng.normal(1.0, 0.3, (m, 2))
    design = np.zeros((2 * m, m))
    for i in range(m):
        unit = [np.cos(headings[i]), np.sin(headings[i])]
        design[2 * i : 2 * i + 2, 0] = np.multiply(unit, dt)
        for c in range(1, i + 1):
            design[2 * i : 2 * i + 2, c] = np.multiply(unit, dt**2)
    penalty = np.zeros((m - 2, m))
    penalty[np.arange(m - 2), np.arange(1, m - 1)] = -1.0
    penalty[-1, -1] = 1.0
    stacked = np.vstack([design, np.sqrt(JERK_PENALTY) * penalty])
    solution = np.linalg.lstsq(stacked, np.concatenate([displacements.ravel(), np.zeros(m - 2)]), rcond=None)[0]
    expected = solution[0] + dt * np.concatenate([[0.0], np.cumsum(solution[1:])])
    projected = np.cos(headings) * displacements[:, 0] + np.sin(headings) * displacements[:, 1]
    np.testing.assert_allclose(speed_fit_matrix(m, dt) @ projected, expected, rtol=0, atol=1e-9)


def test_curvature_fit_is_the_regularised_least_squares_of_its_definition() -> None:
    """Heading step i = v_i dt kappa_i, kappa_i = kappa_0 + dt sum_{1 <= c <= i} rate_c; penalties 1e-10 on kappa_0
    and 1e-2 on every rate. Speeds include standing rows and stops, the rows a vocabulary holds; a row's bits are
    the same alone as among many."""
    rng = np.random.default_rng(3)
    m, dt, count = 40, 0.1, 24
    speed = rng.uniform(0.0, 20.0, (count, m))
    speed[0] = 0.0
    speed[1, 20:] = 0.0
    heading_steps = rng.normal(0.0, 0.03, (count, m))
    weights = np.concatenate([[dt], np.full(m - 1, dt**2)])
    penalty = np.sqrt(np.concatenate([[INITIAL_CURVATURE_PENALTY], np.full(m - 1, CURVATURE_RATE_PENALTY)]))
    together = curvature_profile(heading_steps, speed, dt)
    for row in range(count):
        design = speed[row, :, None] * np.tril(np.ones((m, m))) * weights
        stacked = np.vstack([design, np.diag(penalty)])
        solution = np.linalg.lstsq(stacked, np.concatenate([heading_steps[row], np.zeros(m)]), rcond=None)[0]
        expected = solution[0] + dt * np.concatenate([[0.0], np.cumsum(solution[1:])])
        np.testing.assert_allclose(together[row], expected, rtol=0, atol=1e-9)
        alone = curvature_profile(heading_steps[row : row + 1], speed[row : row + 1], dt)
        assert np.array_equal(alone[0], together[row])


def test_lateral_lqr_equals_the_step_by_step_lookahead() -> None:
    """The unrolled tracker against the 10 step matrices multiplied out, for random ego states off the targets."""
    rng = np.random.default_rng(1)
    dt, wheel_base, horizon = 0.1, 3.089, 10
    targets = interpolate_proposals(np.concatenate([arc(40.0, 9.0), arc(-25.0, 5.0), straight(3.0)]), 0.5)
    reference, terms = tracking_reference(targets, dt, wheel_base)
    steps = np.diff(targets, axis=1)
    speed_fit = (np.cos(targets[:, :-1, 2]) * steps[..., 0] + np.sin(targets[:, :-1, 2]) * steps[..., 1]) @ (
        speed_fit_matrix(40, dt).T
    )
    curvature = curvature_profile(normalize_angle(steps[..., 2]), speed_fit, dt)
    for step in (0, 17, 35):
        ahead = np.minimum(step + np.arange(horizon + 1), 39)
        x, y, heading = targets[:, step].T + rng.normal(0, [0.5, 0.5, 0.05], (3, 3)).T
        speed, steering = rng.uniform(1, 12, 3), rng.normal(0, 0.1, 3)
        commands = [track(reference, n, step, x[n], y[n], heading[n], speed[n], steering[n], terms) for n in range(3)]
        accel, rate = np.array(commands).T
        for n in range(3):
            expected_accel = -10.0 / 11.0 * (speed[n] - speed_fit[n, ahead[-1]])
            lookahead = speed[n] + dt * expected_accel * np.arange(horizon)
            cos, sin = np.cos(targets[n, step, 2]), np.sin(targets[n, step, 2])
            error = np.array([-(x[n] - targets[n, step, 0]) * sin + (y[n] - targets[n, step, 1]) * cos, 0.0, 0.0])
            error[1:] = [normalize_angle(heading[n] - targets[n, step, 2]), steering[n]]
            response = np.zeros(3)
            for k in range(horizon):
                dynamics = np.array([[1, lookahead[k] * dt, 0], [0, 1, lookahead[k] * dt / wheel_base], [0, 0, 1]])
                error = dynamics @ error - [0, lookahead[k] * curvature[n, ahead[k]] * dt, 0]
                response = dynamics @ response + [0, 0, dt]
            error[1:] = normalize_angle(error[1:])
            weights = np.array([1.0, 10.0, 0.0])
            expected_rate = -(response * weights) @ error / ((response * weights) @ response + 1.0)
            assert accel[n] == pytest.approx(expected_accel, abs=1e-12)
            assert rate[n] == pytest.approx(expected_rate, rel=1e-9, abs=1e-12)
