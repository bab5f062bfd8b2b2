"""CARLA sensor frames -> ego, on hand-worked points (CARLA is left-handed: positive yaw and azimuth turn right)."""

import math

import numpy as np

from lead_s2r.closed_loop.sensors import RADARS, Rig, radar_points, sensor_specs
from lead_s2r.formats.carla_rig import radar_to_cartesian, sensor_to_carla_ego
from lead_s2r.geometry import CARLA_REAR_AXLE_TO_CENTER


def test_a_sensor_turned_right_sees_ahead_as_ego_right():
    ego = sensor_to_carla_ego(np.array([[10.0, 0.0, 1.0]]), (2.6, 0.0, 0.6), 90.0)
    np.testing.assert_allclose(ego, [[2.6, 10.0, 1.6]], atol=1e-12)


def test_radar_polar_to_cartesian():
    # depth 10, altitude 0.1 rad up, azimuth 30 deg to the right, closing at 3 m/s
    out = radar_to_cartesian(np.array([[10.0, 0.1, math.radians(30.0), -3.0]]))
    horizontal = 10.0 * math.cos(0.1)
    np.testing.assert_allclose(
        out, [[horizontal * math.cos(math.radians(30)), horizontal * 0.5, 10 * math.sin(0.1), -3]]
    )


def test_front_right_radar_detection_lands_front_right_in_iso():
    # radar_2 looks 45 deg right; a detection straight ahead of it at 10 m: CARLA ego (2.6 + 7.07, +7.07),
    # ISO rear axle (2.6 + 7.07 + 1.389, -7.07)
    data = {name: (0, np.zeros((0, 4), np.float32)) for name, _, _ in RADARS}
    data["radar_2"] = (0, np.array([[10.0, 0.0, 0.0, 1.5]], np.float32))
    points = radar_points(data)
    d = 10.0 / math.sqrt(2)
    np.testing.assert_allclose(points, [[2.6 + d + CARLA_REAR_AXLE_TO_CENTER, -d, 0.6, 1.5, 1.0]], atol=1e-5)


def test_three_camera_rig_sensors_in_stitch_order():
    specs = sensor_specs(Rig("CARLA_LEADERBOARD2_3CAMERAS", lidar=True, radar=False))
    cameras = [(s["id"], s["yaw"], s["width"], s["fov"]) for s in specs if s["type"] == "sensor.camera.rgb"]
    assert cameras == [("rgb_1", -54.5, 384, 60.0), ("rgb_2", 0.0, 384, 60.0), ("rgb_3", 54.5, 384, 60.0)]
    assert [s["yaw"] for s in specs if s["type"] == "sensor.lidar.ray_cast"] == [-90.0, -270.0]
    assert not any(s["type"] == "sensor.other.radar" for s in specs)
