"""The report's views on hand-made samples: camera projection at a hand-worked pixel, the BEV's left is the picture's
left (checked on the PNG's pixels), and failing sub-scores named with their time."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from pdm_scenes import TIMES, agent, drive, road_scene

from lead_s2r.report.bev import LOGGED, PREDICTED, bev_figure, save_figure, trust_region
from lead_s2r.report.camera import camera_figure, forward_cameras, monotonic_radius, project_points
from lead_s2r.report.run_outputs import MetricScores, training_curves
from lead_s2r.report.sample_page import named_failures
from lead_s2r.schema import BoxClass
from lead_s2r.scoring.pdm.observation import log_observation
from lead_s2r.scoring.pdm.score import score_states
from lead_s2r.scoring.rfs import RFSConfig, speed_scale

#: NAVSIM's synthetic front camera: 1.5 m ahead of the rear axle, 1.5 m up, level, OpenCV axes
FRONT = {
    "id": "front",
    "width": 192,
    "height": 108,
    "K": [[154.5, 0.0, 96.0], [0.0, 154.5, 54.0], [0.0, 0.0, 1.0]],
    "distortion": [-0.35, 0.15, 0.0005, -0.0002, -0.03],
    "cam_to_ego": [[0.0, 0.0, 1.0, 1.5], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5], [0.0, 0.0, 0.0, 1.0]],
}


def straight_sample(speed: float = 5.0) -> dict:
    """A sample driving straight along +x at ``speed``, 2 Hz for 4 s, with a plain grey front image."""
    t = 0.5 * np.arange(1, 9)
    future = np.column_stack([t, speed * t, np.zeros_like(t), np.zeros_like(t)]).astype(np.float32)
    ok, jpeg = cv2.imencode(".jpg", np.full((108, 192, 3), 128, np.uint8))
    assert ok
    meta = {"cameras": [FRONT], "vehicle": {"length": 4.8, "width": 2.0, "rear_axle_to_center": 1.4}}
    return {"__key__": "straight", "meta": meta, "future": future, "cam_front": jpeg.tobytes()}


def test_point_10_m_ahead_on_the_logged_path_projects_to_the_hand_worked_pixel() -> None:
    sample = straight_sample()
    point = sample["future"][sample["future"][:, 0] == 2.0, 1:3]  # 5 m/s x 2 s
    assert point.tolist() == [[10.0, 0.0]]
    pixels, inside = project_points(FRONT, np.c_[point, [0.0]])
    # camera frame: x = -y = 0, y = 1.5 m below the lens, z = 10 - 1.5 = 8.5 m; x' = 0, y' = 1.5 / 8.5
    # r2 = y'^2 = 0.0311419; radial = 1 - 0.35 r2 + 0.15 r2^2 - 0.03 r2^3 = 0.9892449
    # x'' = p2 r2 = -6.2284e-6; y'' = y' radial + p1 (r2 + 2 y'^2) = 0.1745726 + 0.0000467 = 0.1746193
    # u = 154.5 x'' + 96 = 95.99904; v = 154.5 y'' + 54 = 80.97869
    np.testing.assert_allclose(pixels[0], [95.99904, 80.97869], atol=1e-4)
    assert inside[0] and pixels[0, 1] > FRONT["K"][1][2]  # in the picture, below the horizon row cy
    behind, in_view = project_points(FRONT, np.array([[-5.0, 0.0, 0.0]]))
    assert not in_view[0] and np.isnan(behind).all()


def test_points_beyond_the_distortion_fold_are_not_drawn() -> None:
    # slope of r (1 - 0.35 r^2 + 0.15 r^4 - 0.03 r^6): 1 - 1.05 r^2 + 0.75 r^4 - 0.21 r^6, 0.042 at 1.5, -0.296 at 1.6
    assert 1.5 < monotonic_radius(np.array(FRONT["distortion"])) < 1.6
    assert monotonic_radius(np.zeros(5)) == np.inf
    # 3 m ahead of the lens and 6 m to the right: r = 2, folded back into the picture by the polynomial
    folded = np.array([[4.5, -6.0, 1.5]])
    raw, _ = cv2.projectPoints(np.array([[6.0, 0.0, 3.0]]), np.zeros(3), np.zeros(3), np.array(FRONT["K"]),
                               np.array(FRONT["distortion"]))  # fmt: skip
    assert 0 <= raw[0, 0, 0] < FRONT["width"]  # the trap: OpenCV puts it inside the image
    pixels, inside = project_points(FRONT, folded)
    assert not inside[0] and np.isnan(pixels).all()


def test_camera_picture_marks_the_logged_path_where_the_calibration_puts_it(tmp_path: Path) -> None:
    sample = straight_sample()
    assert forward_cameras(sample) == [FRONT]
    assert camera_figure(sample, FRONT, {"logged": sample["future"][3:4, 1:3]}, tmp_path / "cam.png")
    image = cv2.imread(str(tmp_path / "cam.png"))
    scale = image.shape[1] / FRONT["width"]  # the figure scales the 192-px picture to its width
    col, row = round(95.99904 * scale), round(80.97869 * scale)
    patch = image[row - 2 : row + 3, col - 2 : col + 3].reshape(-1, 3).astype(int)
    logged_bgr = np.array([int(LOGGED[i : i + 2], 16) for i in (5, 3, 1)])
    assert np.abs(patch - logged_bgr).sum(axis=1).min() < 30


def _pixels_of(image: np.ndarray, color: str) -> np.ndarray:
    """(row, col) of the pixels within a small distance of ``color`` (#rrggbb)."""
    bgr = np.array([int(color[i : i + 2], 16) for i in (5, 3, 1)])
    return np.argwhere(np.abs(image.astype(int) - bgr).sum(axis=-1) < 20)


def test_left_turn_bends_to_the_left_of_the_picture(tmp_path: Path) -> None:
    angle = np.linspace(0.1, np.pi / 2, 10)
    radius = 15.0
    logged = np.column_stack([radius * np.sin(angle), radius * (1 - np.cos(angle))])  # ends at x = 15, y = +15
    predicted = logged * [1.0, 0.7]
    sample = {"__key__": "turn", "meta": {"vehicle": {"length": 4.8, "width": 2.0, "rear_axle_to_center": 1.4}}}
    save_figure(bev_figure(sample, {"logged": logged, "predicted": predicted}), tmp_path / "bev.png")
    image = cv2.imread(str(tmp_path / "bev.png"))
    for color in (LOGGED, PREDICTED):
        pixels = _pixels_of(image, color)
        assert len(pixels) > 50, color
        rows = pixels[:, 0]
        ahead = pixels[rows <= np.quantile(rows, 0.2), 1].mean()  # furthest forward = top of the picture
        start = pixels[rows >= np.quantile(rows, 0.8), 1].mean()
        assert ahead < start - 40, f"{color}: the turn ends at column {ahead:.0f}, right of its start {start:.0f}"


def _scores(family: str) -> MetricScores:
    return MetricScores(Path("."), {"metric": f"{family}@x"}, {})


def failures(scores: MetricScores, row: dict) -> list[str]:
    """The words of each failure :func:`named_failures` names: the list a sample page shows."""
    return [words for _, words in named_failures(scores, row)]


def test_failing_sub_scores_are_named_with_their_time() -> None:
    row = {"valid": True, "no_at_fault_collisions": 0.0, "collision_time_idx": 15, "collision_object_idx": 3,
           "drivable_area_compliance": 0.0,
           "dac_time_idx": 25, "time_to_collision_within_bound": 1.0, "ttc_time_idx": -1, "comfort": 0.0,
           "ego_progress": 0.3}  # fmt: skip
    assert failures(_scores("pdms"), row) == [
        "NC 0: at-fault collision with agent 3 at t = 1.5 s",
        "DAC 0: leaves the drivable area at t = 2.5 s",
        "C 0: acceleration or jerk beyond the comfort bounds",
    ]
    static = {"valid": True, "no_at_fault_collisions": 0.5, "collision_time_idx": 0}
    assert failures(_scores("epdms"), static) == ["NC 0.5: at-fault collision at t = 0.0 s"]
    assert failures(_scores("pdms"), {"valid": False, "error": "no route"}) == ["not scored: no route"]
    rfs = {"rfs": 4.0, "fully_within": False, "best_label": 9.0}
    assert failures(_scores("rfs"), rfs) == ["RFS 4.00: outside every rater's trust region (raised to the floor)"]
    assert failures(_scores("rfs"), {"rfs": 7.5, "fully_within": True, "best_label": 9.0}) == [
        "RFS 7.50: below the best rater's score 9"
    ]
    assert failures(_scores("ade"), {"ade": 3.0}) == []


@pytest.mark.parametrize("speed", [0.0, 5.0, 20.0])
def test_trust_region_half_sizes_follow_the_metric(speed: float) -> None:
    config = RFSConfig()
    rater = np.column_stack([np.arange(1, 21) * 1.0, np.zeros(20)])  # along +x
    corners = trust_region(rater, 11, 0, speed, config)
    scale = float(speed_scale(np.asarray(speed), config))  # 0.5 up to 1.4 m/s, 1.0 from 11 m/s
    np.testing.assert_allclose(corners.max(axis=0) - rater[11], [4.0 * scale, 1.0 * scale])  # 3 s: lng 4, lat 1


def test_training_curves_of_a_prediction_folder_come_from_its_training_root(tmp_path: Path) -> None:
    logs = tmp_path / "run" / "lightning_logs" / "version_0"
    logs.mkdir(parents=True)
    (logs / "metrics.csv").write_text("step,epoch,train/loss,val/loss\n9,0,2.5,\n19,0,1.75,\n19,0,,1.9\n")
    (tmp_path / "run" / "trained").mkdir()
    expected = {"train/loss": [(9.0, 2.5), (19.0, 1.75)], "val/loss": [(19.0, 1.9)]}
    assert training_curves(tmp_path / "run" / "trained") == expected
    assert training_curves(tmp_path / "run") == expected


def test_nc_names_the_agent_row_it_hit() -> None:
    """Two stopped cars, the second in the ego's lane 20 m ahead: a row driving 10 m/s hits agent 1 at step 14 (see
    test_pdm_score's rear-end case); a standing row hits nothing."""
    scene = road_scene([agent(BoxClass.VEHICLE, 20.0, 30.0), agent(BoxClass.VEHICLE, 20.0, 0.0)])
    scores = score_states(scene, np.concatenate([drive(10.0 * TIMES), drive(0.0 * TIMES)]), log_observation(scene), 0)
    assert scores["collision_time_idx"].tolist() == [14, -1]
    assert scores["collision_object_idx"].tolist() == [1, -1]
