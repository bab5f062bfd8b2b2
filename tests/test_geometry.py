import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lead_s2r.geometry import (
    CARLA_REAR_AXLE_TO_CENTER,
    box_corners,
    carla_points_to_iso,
    carla_poses_to_iso,
    flip_y,
    resample,
    to_global,
    to_local,
    wrap_angle,
)

coords = st.floats(-500, 500, allow_nan=False)
angles = st.floats(-np.pi, np.pi, allow_nan=False, exclude_max=True)
pose = st.tuples(coords, coords, angles).map(np.array)
poses = arrays(np.float64, (5, 3), elements=st.floats(-100, 100, allow_nan=False))


def angle_close(a, b):
    return np.allclose(wrap_angle(np.asarray(a) - np.asarray(b) + 1e-12), 0, atol=1e-9)


@given(poses, pose)
def test_local_global_round_trip(p, origin):
    back = to_global(to_local(p, origin), origin)
    assert np.allclose(back[:, :2], p[:, :2], atol=1e-8)
    assert angle_close(back[:, 2], p[:, 2])


@given(poses, pose, pose)
def test_composition(p, a, b):
    """Expressing in frame b, then b's pose in frame a, equals expressing directly in frame a."""
    b_in_a = to_local(b, a)
    direct = to_local(p, a)
    via = to_global(to_local(p, b), b_in_a)
    assert np.allclose(direct[:, :2], via[:, :2], atol=1e-7)
    assert angle_close(direct[:, 2], via[:, 2])


@given(poses)
def test_flip_is_an_involution(p):
    assert np.array_equal(flip_y(flip_y(p, (1, 2)), (1, 2)), p)


def test_wrap_angle_range():
    values = wrap_angle(np.linspace(-20, 20, 1001))
    assert values.min() >= -np.pi and values.max() < np.pi


def carla_left_turn(n: int = 40, radius: float = 10.0) -> np.ndarray:
    """Centre poses of a quarter-circle left turn in CARLA's ego frame (y right, yaw clockwise)."""
    phi = np.linspace(0, np.pi / 2, n)
    x_iso, y_iso = radius * np.sin(phi), radius * (1 - np.cos(phi))
    return np.stack([x_iso, -y_iso, -phi], axis=1)  # left in CARLA = negative y, negative yaw


def test_carla_left_turn_becomes_positive_y():
    iso = carla_poses_to_iso(carla_left_turn())
    assert iso[-1, 1] > 5 and iso[-1, 2] > 1.5
    right = carla_poses_to_iso(flip_y(carla_left_turn(), (1, 2)))
    assert right[-1, 1] < -5 and right[-1, 2] < -1.5


def test_carla_origin_moves_to_rear_axle():
    iso = carla_poses_to_iso(np.zeros((1, 3)))
    assert np.allclose(iso, 0)  # the t0 pose is the origin in both frames
    ahead = carla_points_to_iso(np.array([[10.0, 2.0, 1.0]]))
    assert np.allclose(ahead, [[10 + CARLA_REAR_AXLE_TO_CENTER, -2.0, 1.0]])


def test_carla_turn_keeps_rear_axle_path_inside_centre_path():
    """On a left turn the rear axle tracks inside the centre: its radius about the turn centre is smaller."""
    radius = 10.0
    iso = carla_poses_to_iso(carla_left_turn(radius=radius))
    centre = np.array([CARLA_REAR_AXLE_TO_CENTER, radius])  # turn centre, rear-axle frame
    dist = np.linalg.norm(iso[:, :2] - centre, axis=1)
    assert np.allclose(dist, np.hypot(radius, CARLA_REAR_AXLE_TO_CENTER), atol=1e-9)


def test_resample_linear_and_yaw_unwrapped():
    t = np.array([0.0, 1.0, 2.0])
    values = np.array([[0.0, 0.0, 3.0], [2.0, 1.0, -3.0], [4.0, 2.0, -2.9]])
    out, valid = resample(t, values, np.array([0.5, 1.5, 2.5]), angle_columns=(2,))
    assert valid.tolist() == [True, True, False]
    assert np.allclose(out[:2, :2], [[1.0, 0.5], [3.0, 1.5]])
    midpoint = wrap_angle(3.0 + (2 * np.pi - 6.0) / 2)  # through pi, not through 0
    assert np.isclose(out[0, 2], midpoint)
    assert np.isnan(out[2]).all()


@settings(max_examples=50)
@given(st.integers(2, 30), st.floats(0.05, 1.0))
def test_resample_reproduces_source_grid(n, dt):
    t = np.arange(1, n + 1) * dt
    values = np.stack([t**2, np.sin(t)], axis=1)
    out, valid = resample(t, values, t)
    assert valid.all() and np.allclose(out, values)
    _, valid = resample(t, values, t + dt / 2)
    assert not valid[-1]  # never extrapolates past the last source point


def test_box_corners_turn_with_the_box():
    box = np.array([[1.0, 2.0, 0.0, 4.0, 2.0, 1.5, np.pi / 2, 0, 0, 0]])
    corners = box_corners(box)[0]
    # facing +y: the front-left corner lies ahead (+y) and to the box's left (-x)
    assert np.allclose(corners, [[0.0, 4.0], [0.0, 0.0], [2.0, 0.0], [2.0, 4.0]])
