"""PDM-Closed's pure pieces with hand-worked numbers: IDM steps, paths and their offsets, forecasts, object
selection, red lights, leaders and the unrolled proposals."""

import numpy as np
import pytest
import shapely

from lead_s2r.schema import BoxClass, MapKind
from lead_s2r.scoring.pdm.pdm_closed import (
    Forecast,
    PDMClosedConfig,
    PDMPath,
    _leaders,
    corridor,
    forecast,
    idm_step,
    offset_path,
    red_lights_at_start,
    select_objects,
    target_velocities,
    unroll,
)
from lead_s2r.scoring.pdm.route import discrete_path
from lead_s2r.scoring.pdm.scene import PDMScene
from lead_s2r.scoring.pdm.vehicle import PACIFICA

STRAIGHT = discrete_path(np.array([[0.0, 0.0], [100.0, 0.0]]))


def scene_with(
    poses: list[tuple[float, float, float]],
    velocity: list[tuple[float, float]],
    classes: list[int],
    **map_fields: np.ndarray,
) -> PDMScene:
    """A scene of agents seen at t = 0 (4 x 2 m boxes) on an empty map unless ``map_fields`` give one."""
    count = len(poses)
    fields = {
        "polygon_xy": np.zeros((0, 2)),
        "polygon_offsets": np.zeros(1, np.int64),
        "polygon_id": np.zeros(0, np.int64),
        "polygon_kind": np.zeros(0, np.int64),
        "route_lane_ids": np.zeros(0, np.int64),
        **map_fields,
    }
    return PDMScene(
        **fields,
        centerline=STRAIGHT,
        agent_t=np.array([0.0]),
        agent_poses=np.array(poses, np.float64).reshape(count, 1, 3),
        agent_velocity=np.array(velocity, np.float64).reshape(count, 1, 2),
        agent_valid=np.ones((count, 1), bool),
        agent_size=np.tile([4.0, 2.0, 1.5], (count, 1)),
        agent_class=np.array(classes, np.int64),
        ego_velocity=np.zeros(2),
        ego_acceleration=np.zeros(2),
    )


def test_idm_from_rest_on_a_free_road() -> None:
    lead = np.array([[100.0, 0.0, PACIFICA.length / 2]])
    progress, velocity = idm_step(np.zeros(1), np.zeros(1), lead, np.array([10.0]))
    # gap 100 - 2.588 = 97.412 m, desired gap 1 m: a = 1.5 (1 - (1 / 97.412)^2)
    assert progress[0] == 0.0
    assert velocity[0] == pytest.approx(0.1 * 1.5 * (1 - (1 / 97.412) ** 2), rel=1e-9)


def test_idm_at_its_target_speed_holds_it_and_brakes_hard_for_a_close_leader() -> None:
    far = np.array([[1e6, 0.0, 0.0]])
    assert idm_step(np.zeros(1), np.array([10.0]), far, np.array([10.0]))[1][0] == pytest.approx(10.0, abs=1e-9)
    # the all-zero leader of step 1: gap clamped to 1 m, far below the desired 39.6 m, so the brake saturates at 3
    progress, velocity = idm_step(np.zeros(1), np.array([10.0]), np.zeros((1, 3)), np.array([10.0]))
    assert progress[0] == pytest.approx(1.0) and velocity[0] == pytest.approx(9.7)


def test_target_velocities_fall_back_to_15_mps() -> None:
    np.testing.assert_allclose(target_velocities(10.0), [2, 4, 6, 8, 10])
    np.testing.assert_allclose(target_velocities(float("nan")), [3, 6, 9, 12, 15])


def test_offset_path_moves_left_of_the_heading() -> None:
    north = np.array([[0.0, 0.0, np.pi / 2], [0.0, 10.0, np.pi / 2]])
    np.testing.assert_allclose(offset_path(STRAIGHT, 1.0)[:, :2], [[0, 1], [100, 1]], atol=1e-12)
    np.testing.assert_allclose(offset_path(north, -1.0)[:, :2], [[1, 0], [1, 10]], atol=1e-12)


def test_path_interpolates_clips_projects_and_cuts() -> None:
    path = PDMPath(discrete_path(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])))
    assert path.length == 20.0
    np.testing.assert_allclose(path.interpolate(5.0), [5.0, 0.0, np.pi / 4])
    np.testing.assert_allclose(path.interpolate(-3.0), [1e-5, 0.0, np.pi / 2 * 1e-6], atol=1e-12)
    np.testing.assert_allclose(path.interpolate(99.0), [10.0, 10.0, np.pi / 2])
    assert path.project(np.array([5.0, 3.0])) == pytest.approx(5.0)
    # only the corner vertex lies in [2, 12]: shapely's substring takes over
    assert path.substring(2.0, 12.0).length == pytest.approx(10.0)
    assert shapely.get_coordinates(path.substring(0.0, 20.0)).tolist() == [[0, 0], [10, 0], [10, 10]]


def test_forecast_moves_agents_every_two_steps_and_keeps_static_objects() -> None:
    scene = scene_with(
        [(20.0, 0.0, 0.0), (20.0, 5.0, 0.0), (30.0, -5.0, 0.0)],
        [(5.0, 0.0), (-2.0, 0.0), (1.0, 0.0)],
        [BoxClass.VEHICLE, BoxClass.VEHICLE, BoxClass.TRAFFIC_CONE],
    )
    result = forecast(scene)
    assert result.poses.shape == (3, 51, 3)
    # static objects come first; the reversing car moves along heading + pi
    np.testing.assert_allclose(result.poses[:, 1, 0], [30.0, 20.0, 20.0])
    np.testing.assert_allclose(result.poses[:, 2, 0], [30.0, 21.0, 19.6])
    np.testing.assert_allclose(result.poses[:, 3, 0], [30.0, 21.0, 19.6])
    np.testing.assert_allclose(result.poses[:, 50, 0], [30.0, 45.0, 10.0])
    np.testing.assert_allclose(result.speed, [0.0, 5.0, 2.0])


def test_select_objects_drops_far_and_overlapping_ones_and_caps_each_class() -> None:
    poses = [(3.0, 0.0, 0.0), (150.0, 0.0, 0.0)] + [(10.0 + i, 20.0, 0.0) for i in range(12)]
    classes = [BoxClass.VEHICLE, BoxClass.VEHICLE] + [BoxClass.BICYCLE] * 12
    rows = select_objects(scene_with(poses, [(0.0, 0.0)] * len(poses), classes))
    assert rows.tolist() == list(range(2, 12))  # the 10 nearest bicycles; the overlapping and the far car go


def test_red_lights_are_red_on_route_connectors_not_holding_the_ego() -> None:
    square = [[20, -2], [30, -2], [30, 2], [20, 2]]
    around_ego = [[-5, -5], [10, -5], [10, 5], [-5, 5]]
    scene = scene_with(
        [],
        [],
        [],
        polygon_xy=np.array(square + square + around_ego, np.float64),
        polygon_offsets=np.array([0, 4, 8, 12]),
        polygon_id=np.array([7, 8, 9]),
        polygon_kind=np.full(3, MapKind.LANE_CONNECTOR),
        route_lane_ids=np.array([7, 9]),
    )
    scene.red_light_ids, scene.red_light_offsets = np.array([7, 8, 9]), np.array([0, 3])
    (polygon,) = red_lights_at_start(scene)
    assert polygon.bounds == (20.0, -2.0, 30.0, 2.0)


def observation_of(poses: list[tuple[float, float, float]], speed: list[float]) -> Forecast:
    count = len(poses)
    return Forecast(
        poses=np.repeat(np.array(poses, np.float64).reshape(count, 1, 3), 51, axis=1),
        velocity=np.zeros((count, 51, 2)),
        size=np.tile([4.0, 2.0, 1.5], (count, 1)),
        agent_class=np.zeros(count, np.int64),
        speed=np.array(speed, np.float64),
        heading=np.array([p[2] for p in poses]),
        red_lights=[],
    )


def test_leader_is_the_nearest_object_ahead_in_the_corridor() -> None:
    path = PDMPath(STRAIGHT)
    area = corridor(path, 0.0, 75.0, PACIFICA.width)
    observation = observation_of([(30.0, 0.0, np.pi / 3), (-20.0, 0.0, 0.0), (50.0, 10.0, 0.0)], [4.0, 9.0, 9.0])
    lead = _leaders(path, area, observation, 2, np.array([0.0]), np.zeros((1, 3)), PACIFICA)
    # the car's rear corner (30 - 2 cos60 - sin60, -2 sin60 + cos60) lies just right of the ego's front-right one
    corner = np.array(
        [30.0 - 2.0 * np.cos(np.pi / 3) - np.sin(np.pi / 3), -2.0 * np.sin(np.pi / 3) + np.cos(np.pi / 3)]
    )
    gap = np.hypot(corner[0] - PACIFICA.front_length, -corner[1] - PACIFICA.width / 2)
    np.testing.assert_allclose(lead[0], [gap, 4.0 * np.cos(np.pi / 3), 0.0], atol=1e-9)
    free = _leaders(path, area, observation_of([], []), 2, np.array([0.0]), np.zeros((1, 3)), PACIFICA)
    np.testing.assert_allclose(free[0], [100.0, 0.0, PACIFICA.length / 2])


def test_leader_row_is_carried_from_proposal_to_proposal() -> None:
    path = PDMPath(STRAIGHT)
    area = corridor(path, 0.0, 75.0, PACIFICA.width)
    observation = observation_of([(30.0, 0.0, 0.0)], [4.0])
    poses = np.array([[40.0, 0.0, 0.0], [0.0, 0.0, 0.0], [50.0, 0.0, 0.0]])
    lead = _leaders(path, area, observation, 2, poses[:, 0], poses, PACIFICA)
    half = PACIFICA.length / 2
    # free; a leader keeps the free row's rear length; free again keeps the leader's speed
    np.testing.assert_allclose(
        lead, [[100.0, 0.0, half], [28.0 - PACIFICA.front_length, 4.0, half], [100.0, 4.0, half]]
    )


def test_unroll_copies_the_zero_leader_at_step_one_then_drives_free() -> None:
    state = unroll(PDMPath(STRAIGHT), np.array([10.0]), 0.0, observation_of([], []), 2, PACIFICA)
    assert state.idm[0, 1, 1] == 0.0  # a = 1.5 (1 - 0 - (1 / 1)^2) = 0
    assert state.idm[0, 2, 1] == pytest.approx(0.1 * 1.5 * (1 - (1 / 97.412) ** 2), rel=1e-9)
    extended = unroll(PDMPath(STRAIGHT), np.array([10.0]), 0.0, observation_of([], []), 4, PACIFICA, state=state)
    assert extended.done == 4 and extended.idm[0, 4, 0] > extended.idm[0, 3, 0] > 0.0
    np.testing.assert_allclose(extended.poses[0, :5, 1:], 0.0, atol=1e-12)
    assert PDMClosedConfig().trajectory_steps + 1 == extended.poses.shape[1]
