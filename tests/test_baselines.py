import numpy as np
from toy_adapter import toy_sample

from lead_s2r.scoring.baselines import NAVSIM_GRID, constant_turn_rate, predict_constant_velocity


def test_straight_line_at_constant_speed():
    poses = constant_turn_rate(10.0, 0.0, np.array([0.5, 1.0, 2.0]))
    assert np.allclose(poses, [[5, 0, 0], [10, 0, 0], [20, 0, 0]])


def test_left_turn_has_positive_y_and_stays_on_its_circle():
    speed, yaw_rate = 8.0, 0.4
    poses = constant_turn_rate(speed, yaw_rate, np.linspace(0.1, 3, 30))
    assert (poses[:, 1] > 0).all() and (poses[:, 2] > 0).all()
    radius = speed / yaw_rate
    assert np.allclose(np.hypot(poses[:, 0], poses[:, 1] - radius), radius)
    steps = np.diff(np.vstack([[0, 0], poses[:, :2]]), axis=0)
    assert np.isclose(np.linalg.norm(steps, axis=1).sum(), speed * 3, rtol=1e-3)  # arc length = speed * time


def test_constant_velocity_drives_straight_at_the_current_speed_whatever_the_turn_rate():
    sample = toy_sample("log000", 0, yaw_rate=-0.1)
    prediction = predict_constant_velocity(sample)
    speed = np.hypot(*sample["meta"]["ego"]["velocity"])
    assert np.array_equal(prediction.t, NAVSIM_GRID.astype(np.float32))
    assert np.allclose(prediction.xy, np.column_stack([speed * NAVSIM_GRID, np.zeros(8)]))
    assert (prediction.yaw == 0).all()
