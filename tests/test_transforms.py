import math
import warnings

import cv2
import numpy as np
import pytest
import torch
from tiny_models import sensor_spec
from toy_adapter import toy_sample

from lead_s2r.data.camera_layout import Band, Tile, camera_layout
from lead_s2r.data.collate import collate
from lead_s2r.data.lead_labels import bev_labels
from lead_s2r.data.lead_route import lead_route
from lead_s2r.data.lidar import rasterize_lidar
from lead_s2r.data.radar import radar_targets
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.models.config import NAVSIM_VERTICAL_FOV_DEG, BEVGrid, TrajectoryGrid

GRID = BEVGrid(-32.0, 64.0, -40.0, 40.0, 4.0)


def transform(**overrides) -> SourceTransform:
    spec = sensor_spec(**{"image_size": (32, 64), "trajectory_grids": {"toy": TrajectoryGrid(6, 0.5)}, **overrides})
    return SourceTransform("toy", spec, ["front"])


def test_future_is_resampled_onto_the_model_grid_and_masked_past_the_horizon():
    sample = toy_sample("log000", 0, yaw_rate=0.2)  # future: 8 points at 2 Hz, 4 s
    out = transform(trajectory_grids={"toy": TrajectoryGrid(10, 0.5)})(sample)
    assert out["waypoints_valid"].tolist() == [True] * 8 + [False] * 2
    assert torch.allclose(out["waypoints"][:8], torch.from_numpy(sample["future"][:, 1:3]))
    assert (out["waypoints"][1:8, 1] > 0).all()  # a left turn stays on the left


def test_waypoints_between_source_points_are_interpolated():
    sample = toy_sample("log000", 0, yaw_rate=0.0)  # x = 5 t
    result = transform(trajectory_grids={"toy": TrajectoryGrid(4, 0.25)})(sample)
    assert torch.allclose(result["waypoints"][:, 0], torch.tensor([1.25, 2.5, 3.75, 5.0]))  # first knot is the origin


def test_image_is_rgb_at_the_configured_size():
    sample = toy_sample("log000", 0)
    out = transform()(sample)
    assert out["rgb"].shape == (3, 32, 64) and out["rgb"].dtype == torch.uint8


def test_lidar_cells_follow_x_along_rows_and_y_along_columns():
    raster = rasterize_lidar(np.array([[10.0, 5.0, 0, 0]] * 7 + [[-31.9, -39.9, 0, 0], [100.0, 0, 0, 0]]), GRID)
    assert raster.shape == (384, 320)
    assert raster.dtype == np.uint8 and raster[(10 + 32) * 4, (5 + 40) * 4] == 5  # 7 hits, saturated at 5
    assert raster[0, 0] == 1 and raster.sum() == 6  # the out-of-range point is dropped


def test_bev_labels_follow_the_pixel_to_ego_map():
    # a 2 px/m, 50 m raster centred on the ego, rows along -x, columns along -y (image convention, forward up)
    labels = np.zeros((100, 100), np.uint8)
    labels[50 - 2 * 10, 50 - 2 * 5] = 7  # x = 10 m ahead, y = 5 m left
    spec = {"pixel_to_ego": [[0.0, -0.5, 25.0], [-0.5, 0.0, 25.0]]}
    out = bev_labels(labels, spec, GRID)
    hits = np.argwhere(out == 7)
    assert len(hits) == 4  # one source pixel covers 2 x 2 cells at 4 px/m
    x = GRID.x_min + (hits[:, 0] + 0.5) / 4
    y = GRID.y_min + (hits[:, 1] + 0.5) / 4
    assert np.all(np.abs(x - 10) <= 0.25) and np.all(np.abs(y - 5) <= 0.25)
    assert out[-1, 0] == 255 and out[0, 0] == 255  # x = 64 m and x = -32 m lie outside the raster: no label
    assert out[32 * 4, 40 * 4] == 0  # the ego cell is inside


def test_lead_route_pursues_the_route_and_continues_past_its_end():
    """LEAD's smooth_path: 2.5 m towards the first point, then 1 m chords towards each next one, then on along the
    last two points; repeated points count once; nothing to pursue is masked."""
    route = np.stack([np.linspace(3, 8, 6), np.zeros(6)], axis=1)
    out = lead_route(np.vstack([route[:1], route]), 10)
    assert out["route_valid"].all()
    assert torch.allclose(out["route"], torch.tensor([[2.5 + k, 0.0] for k in range(10)]))
    turn = lead_route(np.array([[3.0, 0.0], [3.0, 3.0]]), 3)["route"].double()  # 2.5 ahead, then towards (3, 3)
    assert torch.allclose(turn[0], torch.tensor([2.5, 0.0], dtype=torch.float64))
    assert torch.allclose(turn[1], torch.tensor([2.5, 0.0], dtype=torch.float64) + torch.tensor([0.5, 3.0]) / 9.25**0.5)
    assert float((turn[2] - turn[1]).norm()) == pytest.approx(1.0, abs=1e-6) and float(turn[2, 0]) == pytest.approx(3.0)
    for short in (np.zeros((0, 2)), np.array([[4.0, 0.0]]), np.array([[4.0, 0.0], [np.nan, 1.0]])):
        assert not lead_route(short, 10)["route_valid"].any()


def test_collate_masks_labels_a_sample_lacks():
    vehicle_boxes = transform(lead_box_classes={"toy": 1})
    sample = toy_sample("log000", 0)
    sample["boxes"][:, 3:6] = np.abs(sample["boxes"][:, 3:6]) + 1.0  # the toy's random sizes: real boxes
    with_future = vehicle_boxes(sample)
    without = transform()({k: v for k, v in toy_sample("log000", 1).items() if k != "future"})  # no box labels
    batch = collate([with_future, without])
    assert batch["waypoints_valid"][1].sum() == 0 and batch["waypoints_valid"][0].all()
    assert (batch["lead_box_heatmap"][1] == -1).all() and not batch["lead_box_weight"][1].any()  # no boxes: ignored
    assert batch["__key__"] == ["toy_log000_000000", "toy_log000_000001"]


class _CollatedInWorker(torch.utils.data.Dataset):
    """Each item is a batch collated inside the dataloader worker, with whether its tensors were born shared."""

    def __len__(self) -> int:
        return 1

    def __getitem__(self, index: int) -> dict:
        samples = [{"__key__": f"k{i}", "x": torch.full((2, 3), i, dtype=torch.uint8)} for i in range(4)]
        batch = collate(samples)
        return {"x": batch["x"], "born_shared": batch["x"].is_shared(), "keys": batch["__key__"]}


def test_collate_stacks_into_shared_memory_in_a_worker_and_not_in_the_main_process():
    loader = torch.utils.data.DataLoader(_CollatedInWorker(), batch_size=None, num_workers=1)
    (got,) = list(loader)
    assert got["born_shared"] is True  # no second copy into shared memory to send it
    assert got["keys"] == ["k0", "k1", "k2", "k3"] and got["x"][:, 0, 0].tolist() == [0, 1, 2, 3]
    assert not collate([{"x": torch.zeros(2)}, {"x": torch.ones(2)}])["x"].is_shared()


def test_collate_brings_labels_of_rigs_of_different_sizes_onto_the_image_grid():
    rng = np.random.default_rng(0)
    small_depth = rng.uniform(0, 50, (2, 3)).astype(np.float32)  # a rig whose labels are stored at half size
    small_ids = np.array([[0, 1, 2], [3, 255, 5]], np.uint8)  # 255: no label
    full_depth, full_ids = rng.uniform(0, 50, (4, 6)).astype(np.float32), np.full((4, 6), 7, np.uint8)
    rgb = torch.zeros(3, 4, 6, dtype=torch.uint8)
    batch = collate(
        [
            {"rgb": rgb, "depth": torch.from_numpy(small_depth), "semantic": torch.from_numpy(small_ids)},
            {"rgb": rgb, "depth": torch.from_numpy(full_depth), "semantic": torch.from_numpy(full_ids)},
        ]
    )
    assert batch["depth"].shape == batch["semantic"].shape == (2, 4, 6) and batch["semantic"].dtype == torch.uint8
    expected = cv2.resize(small_depth, (6, 4), interpolation=cv2.INTER_LINEAR)  # what the loader's render does
    np.testing.assert_allclose(batch["depth"][0].numpy(), expected, rtol=1e-6)
    np.testing.assert_array_equal(batch["semantic"][0].numpy(), small_ids.repeat(2, 0).repeat(2, 1))
    np.testing.assert_array_equal(batch["depth"][1].numpy(), full_depth)
    np.testing.assert_array_equal(batch["semantic"][1].numpy(), full_ids)


def test_a_future_without_yaw_gives_no_heading_target():
    sample = toy_sample("log000", 0)
    sample["future"][:, 3] = np.nan  # WOD-E2E stores no heading
    out = transform()(sample)
    assert "headings" not in out and out["waypoints_valid"].any()


def test_radar_targets_are_the_boxes_radar_points_hit_fastest_first():
    boxes = np.zeros((3, 10), np.float32)
    boxes[:, :2] = [[10, 0], [20, 5], [30, -5]]
    boxes[:, 3:5] = [4.0, 2.0]
    boxes[:, 6] = [0.0, np.pi / 2, 0.0]  # the second box is turned: 2 m along x, 4 m along y
    boxes[:, 7] = [3.0, 8.0, 1.0]
    radar = np.array([[11.5, 0.5, 0, 2, 0], [20.0, 6.8, 0, 7, 1], [40.0, 0, 0, 0, 2]], np.float32)
    out = radar_targets(radar, boxes)
    assert out["radar_targets_valid"].tolist()[:3] == [True, True, False]
    assert torch.allclose(out["radar_targets"][:2], torch.tensor([[20.0, 5.0, 8.0], [10.0, 0.0, 3.0]]))


CARLA_FOCAL = 192 / math.tan(math.radians(30))  # a 384 px tile with a 60 deg fov
CARLA_TILES = tuple(Tile(384 * i, 384 * (i + 1), CARLA_FOCAL, 192.0) for i in range(3))


def test_carla_mosaic_is_letterboxed_into_ltfv6_not_squashed():
    full = camera_layout((((384, 1152), CARLA_TILES),), (270, 1920), None)
    assert full.bands == ((Band(0, 1152, 0, 384),),)  # three tiles with the same rows: one band
    assert full.strip == (384, 1152) and full.box == (0, 555, 270, 810)  # scale 270 / 384, centred
    # at NAVSIM's vertical fov: rows 192 +- 332.55 tan(19.27 deg) = 192 +- 116.2 -> [76, 308), then scale 270 / 232
    navsim_fov = camera_layout((((384, 1152), CARLA_TILES),), (270, 1920), NAVSIM_VERTICAL_FOV_DEG)
    assert navsim_fov.bands == ((Band(0, 1152, 76, 308),),)
    assert navsim_fov.box == (0, 289, 270, 1341) and navsim_fov.letterboxed


def test_navsim_four_cameras_fill_ltfv6_exactly():
    camera = ((1080, 1920), (Tile(0, 1920, 1545.0, 540.0),))
    layout = camera_layout((camera,) * 4, (270, 1920), NAVSIM_VERTICAL_FOV_DEG)
    assert layout.bands == ((Band(0, 1920, 0, 1080),),) * 4 and layout.box == (0, 0, 270, 1920)
    assert not layout.letterboxed


def mosaic_sample(cy: float = 16.0) -> dict:
    """A 3-tile 96x32 mosaic (fy = 16: a 90 deg vertical fov) with an 8x8 white square and class-3 label at the
    centre of each tile, and a red marker row at row 2."""
    sample = toy_sample("log000", 0)
    image = np.zeros((32, 96, 3), np.uint8)
    semantic = np.zeros((32, 96), np.uint8)
    for tile in range(3):
        image[12:20, 32 * tile + 12 : 32 * tile + 20] = 255
        semantic[12:20, 32 * tile + 12 : 32 * tile + 20] = 3
    image[2, :] = (0, 0, 255)
    sample["cam_mosaic"] = cv2.imencode(".png", image)[1].tobytes()  # lossless: exact pixel checks
    sample["semantic_mosaic"] = semantic
    sample["meta"]["cameras"] = [
        {
            "id": "mosaic",
            "width": 32,
            "height": 32,
            "K": [[16.0, 0, 16], [0, 16.0, cy], [0, 0, 1]],
            "tile": [32 * i, 32],
        }
        for i in range(3)
    ]
    return sample


def mosaic_transform(**overrides) -> SourceTransform:
    """A transform reading camera field ``mosaic`` with CARLA's perspective label space."""
    grids = {"toy": TrajectoryGrid(6, 0.5)}
    return SourceTransform(
        "toy", sensor_spec(trajectory_grids=grids, label_space={"toy": "carla"}, **overrides), ["mosaic"]
    )


def square_extent(mask: np.ndarray) -> tuple[int, int]:
    """Height and width of the first square (connected run of True) in a boolean image."""
    rows, cols = np.nonzero(mask)
    first = cols < cols.min() + 20
    return int(rows[first].max() - rows[first].min() + 1), int(cols[first].max() - cols[first].min() + 1)


def test_a_strip_of_another_aspect_is_letterboxed_with_a_warning_and_labels_follow():
    transform = mosaic_transform(image_size=(32, 192))
    with pytest.warns(UserWarning, match=r"96x32 strip \(aspect 3.00\).*192x32 \(aspect 6.00\); letterboxed"):
        out = transform(mosaic_sample())
    rgb = out["rgb"].numpy()
    assert (rgb[:, :, :48] == 0).all() and (rgb[:, :, 144:] == 0).all()  # pillars either side
    white = (rgb > 200).all(axis=0)
    assert square_extent(white) == (8, 8)  # a square stays a square (squashed: 8 high, 16 wide)
    semantic = out["semantic"].numpy()
    assert (semantic[:, :48] == 255).all() and (semantic[:, 144:] == 255).all()  # no label on the pillars
    np.testing.assert_array_equal(semantic == 3, white)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        transform(mosaic_sample())  # once per rig, not once per sample


def test_tiles_are_cut_to_the_vertical_fov_around_their_principal_point():
    # fov 2 atan(8 / 16): 16 rows around cy = 12 -> rows [4, 20), which fill a 6:1 model image at scale 2
    fov = 2 * math.degrees(math.atan(8 / 16))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the cut strip has the model's aspect: no warning
        out = mosaic_transform(image_size=(32, 192), vertical_fov_deg=fov)(mosaic_sample(cy=12.0))
    rgb = out["rgb"].numpy()
    white = (rgb > 200).all(axis=0)
    rows = np.nonzero(white.any(axis=1))[0]
    assert (rows.min(), rows.max()) == (16, 31)  # source rows 12..19 -> (12 - 4) * 2 .. (20 - 4) * 2 - 1
    assert square_extent(white) == (16, 16)
    red = (rgb[0] > 200) & (rgb[2] < 50)
    assert not red.any()  # row 2 lies outside the band
    np.testing.assert_array_equal(out["semantic"].numpy() == 3, white)


def test_a_band_beyond_the_camera_is_padded():
    # fov 2 atan(24 / 16) > the camera's 90 deg: rows [-8, 40) of a 32-row tile, 8 padded rows above and below
    layout = camera_layout((((32, 96), (Tile(0, 96, 16.0, 16.0),)),), (48, 96), 2 * math.degrees(math.atan(1.5)))
    assert layout.bands == ((Band(0, 96, -8, 40),),) and not layout.letterboxed
    out = mosaic_transform(image_size=(48, 96), vertical_fov_deg=2 * math.degrees(math.atan(1.5)))(mosaic_sample())
    assert (out["rgb"].numpy()[:, :8] == 0).all() and (out["semantic"].numpy()[:8] == 255).all()
    assert (out["rgb"].numpy()[:, 8 + 2] > 200).any()  # the red marker row moved down by the padding


def test_a_near_match_is_stretched_without_warning():
    transform = mosaic_transform(image_size=(32, 97))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert transform(mosaic_sample())["rgb"].shape == (3, 32, 97)


def test_fov_crop_needs_calibration_and_ablations_need_a_full_mosaic():
    sample = mosaic_sample()
    del sample["meta"]["cameras"]
    with pytest.raises(ValueError, match=r"source 'toy'.*calibration"):
        mosaic_transform(image_size=(32, 96), vertical_fov_deg=40.0)(sample)
    with pytest.raises(ValueError, match="camera ablations"):
        mosaic_transform(image_size=(32, 192), equal_tiles=True)(mosaic_sample())
