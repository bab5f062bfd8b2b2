"""The fast transforms against their straightforward definitions, kept here as the reference.

Each reference is the plain form of what the transform computes (one Gaussian over the whole grid per box, one
nearest-pixel lookup per cell, a full-size BGR decode resampled by the layout). Outputs must be bit-identical,
except an image decoded at reduced JPEG size, which stays within the stated tolerance. Where the batch contract is
leaner than the reference (uint8 LiDAR counts, uint8 class maps with 255 = ignore), the comparison goes through the
functions the model and the losses apply on the device (``lidar_input``, ``class_ids``).
"""

import math

import cv2
import numpy as np
import pytest
import torch
from tiny_models import sensor_spec

from lead_s2r.data.camera_input import jpeg_reduction
from lead_s2r.data.camera_layout import CameraLayout, Tile, camera_layout, render
from lead_s2r.data.lead_labels import (
    LeadBevClass,
    _bev_tables,
    _footprint_pixels,
    _on_occupancy_canvas,
    bev_cell_centres,
    bev_gather,
    bev_gather_index,
    bev_labels,
    box_points,
    canvas_crop,
    draw_lead_boxes,
    footprint_rects,
    lead_bev_labels,
    lead_hdmap_canvas,
)
from lead_s2r.data.lidar import rasterize_lidar
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.geometry import raster_lookup
from lead_s2r.models.config import CARLA_BEV, NAVSIM_BEV, NAVSIM_VERTICAL_FOV_DEG, BEVGrid
from lead_s2r.models.inputs import IGNORE_CLASS, LIDAR_HITS_MAX, class_ids, lidar_input, on_image_grid
from lead_s2r.schema import BoxClass

# --------------------------------------------------------------------------- references


def camera_image(transform: SourceTransform, sample: dict) -> tuple[torch.Tensor, CameraLayout]:
    """The transform's camera input of ``sample`` and its layout, by whichever decode path the rig takes."""
    plan = transform.camera.plan(sample)
    return transform.camera.image(sample, plan), plan.layout


def random_boxes(rng: np.random.Generator, n: int) -> np.ndarray:
    boxes = np.zeros((n, 10), np.float32)
    boxes[:, 0] = rng.uniform(-40, 70, n)  # some fall off the CARLA grid (x in [-32, 64))
    boxes[:, 1] = rng.uniform(-45, 45, n)
    boxes[:, 2] = rng.uniform(0, 2, n)
    boxes[:, 3] = rng.uniform(0.5, 14, n)  # up to bus-sized: sigma above the 0.5-cell floor
    boxes[:, 4] = rng.uniform(0.5, 9, n)
    boxes[:, 5] = rng.uniform(1, 4, n)
    boxes[:, 6] = rng.uniform(-math.pi, math.pi, n)
    boxes[:, 7:9] = rng.normal(0, 5, (n, 2))
    boxes[:, 9] = rng.integers(0, 12, n)  # classes 10 and 11 are beyond a 10-class head
    return boxes


def reference_bev_labels(labels: np.ndarray, pixel_to_ego: list, grid: BEVGrid) -> np.ndarray:
    xs, ys = bev_cell_centres(grid)
    x, y = np.meshgrid(xs, ys, indexing="ij")
    return raster_lookup(labels, pixel_to_ego, x, y)


def reference_lidar(points: np.ndarray, grid: BEVGrid) -> np.ndarray:
    h, w = grid.shape
    rows = np.floor((points[:, 0] - grid.x_min) * grid.pixels_per_meter).astype(np.int64)
    cols = np.floor((points[:, 1] - grid.y_min) * grid.pixels_per_meter).astype(np.int64)
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    counts = np.bincount(rows[inside] * w + cols[inside], minlength=h * w).reshape(h, w)
    return (np.minimum(counts, LIDAR_HITS_MAX) / LIDAR_HITS_MAX).astype(np.float32)


def reference_camera(transform: SourceTransform, sample: dict) -> dict[str, np.ndarray]:
    """Full-size BGR decode, the layout of the decoded shapes applied to image and labels, as the definition."""
    images = [cv2.imdecode(np.frombuffer(sample[f"cam_{c}"], np.uint8), cv2.IMREAD_COLOR) for c in transform.cameras]
    layout = transform.camera.plan_for(sample["meta"], [image.shape[:2] for image in images]).layout
    rgb = render(layout, images, cv2.INTER_AREA, 0)
    out = {"rgb": np.ascontiguousarray(rgb[:, :, ::-1].transpose(2, 0, 1))}
    camera = transform.cameras[0]
    if f"semantic_{camera}" in sample:
        semantic = sample[f"semantic_{camera}"].astype(np.int16)
        out["semantic"] = render(layout, [semantic], cv2.INTER_NEAREST, -1).astype(np.int64)
    if f"depth_{camera}" in sample:
        metres = sample[f"depth_{camera}"].astype(np.float32) / 255.0 * float(sample["meta"]["depth"]["max_m"])
        out["depth"] = render(layout, [metres], cv2.INTER_LINEAR, 0.0)
    return out


# --------------------------------------------------------------------------- data


@pytest.mark.parametrize(
    "pixel_to_ego",
    [
        [[0.0, -0.5, 65.139], [-0.5, 0.0, 63.75]],  # LEAD's hdmap: 2 px/m, rows along -x, columns along -y
        [[0.25, 0.0, -20.0], [0.0, 0.25, -31.0]],  # axis-aligned, 4 px/m, partly outside the grid
        [[0.3, -0.4, 3.0], [0.4, 0.3, -7.0]],  # rotated and scaled
    ],
)
@pytest.mark.parametrize("grid", [CARLA_BEV, NAVSIM_BEV])
def test_bev_labels_equal_the_per_cell_lookup(pixel_to_ego: list, grid: BEVGrid) -> None:
    labels = np.random.default_rng(1).integers(0, 11, (256, 200), dtype=np.uint8)
    expected = reference_bev_labels(labels, pixel_to_ego, grid)
    got = bev_labels(labels, {"pixel_to_ego": pixel_to_ego}, grid)
    assert expected.dtype == np.int64 and got.dtype == np.uint8  # widened by the loss, on the device
    np.testing.assert_array_equal(class_ids(torch.from_numpy(got)).numpy(), expected)
    assert (expected == -1).any() or grid is NAVSIM_BEV  # the raster does not cover every grid


def test_bev_labels_follow_each_samples_raster_not_a_cached_one() -> None:
    spec = {"pixel_to_ego": [[0.0, -0.5, 65.139], [-0.5, 0.0, 63.75]]}
    first, second = np.zeros((256, 256), np.uint8), np.full((256, 256), 7, np.uint8)
    bev_labels(first, spec, CARLA_BEV)
    assert set(np.unique(bev_labels(second, spec, CARLA_BEV))) <= {IGNORE_CLASS, 7}


@pytest.mark.parametrize(
    "pixel_to_ego",
    [
        [[0.0, -0.5, 65.139], [-0.5, 0.0, 63.75]],  # LEAD's hdmap
        [[0.25, 0.0, -20.0], [0.0, 0.25, -31.0]],  # axis-aligned, partly outside the grid
        [[0.3, -0.4, 3.0], [0.4, 0.3, -7.0]],  # rotated and scaled
    ],
)
@pytest.mark.parametrize("grid", [CARLA_BEV, NAVSIM_BEV])
@pytest.mark.parametrize("leaderboard", [True, False])
def test_lead_bev_labels_from_the_raster_equal_the_remap_and_turns_after_the_gather(
    pixel_to_ego: list, grid: BEVGrid, leaderboard: bool
) -> None:
    """The remap and the first quarter turn folded into the gather (:func:`lead_hdmap_canvas`) give
    :func:`lead_bev_labels` of the gathered hdmap, boxes and lights drawn over: every id, IGNORE_CLASS included,
    through the LUT; the index turned, not transposed."""
    rng = np.random.default_rng(3)
    raster = rng.integers(0, 256, (256, 200), dtype=np.uint8)
    raster[:, :20] = IGNORE_CLASS
    boxes = random_boxes(rng, 60).astype(np.float64)
    boxes[:, 9] = rng.integers(0, len(BoxClass), 60)
    lights = np.where(rng.random(60) < 0.1, rng.integers(0, 13, 60), -1)
    spec = {"pixel_to_ego": pixel_to_ego}
    gathered = bev_labels(raster, spec, grid)
    expected = lead_bev_labels(gathered.copy(), boxes, grid, leaderboard, lights)
    canvas = lead_hdmap_canvas(raster, spec, grid, leaderboard)
    assert canvas.flags.c_contiguous and canvas.shape == grid.shape[::-1]
    got = draw_lead_boxes(canvas, boxes, grid, leaderboard, lights)
    assert got.dtype == expected.dtype and got.shape == expected.shape
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(bev_labels(raster, spec, grid), gathered)  # the two cached indices stay apart


def test_bev_gather_copies_rows_and_columns_where_they_read_the_flat_indexs_pixels() -> None:
    """LEAD's hdmap in LEAD's layout (and an axis-aligned raster in ours) is gathered by rows and columns, a rotated
    raster by the flat index; each reads, cell by cell, the pixel (or the fill) the flat index does."""
    lead_hdmap, aligned, rotated = (
        [[0.0, -0.5, 65.139], [-0.5, 0.0, 63.75]],
        [[0.25, 0.0, -20.0], [0.0, 0.25, -31.0]],
        [[0.3, -0.4, 3.0], [0.4, 0.3, -7.0]],
    )
    padded = np.random.default_rng(4).integers(0, 255, (257, 201), dtype=np.uint8)
    for pixel_to_ego, turned, separable in ((lead_hdmap, True, True), (aligned, False, True), (rotated, True, False)):
        key = tuple(tuple(row) for row in pixel_to_ego)
        gather = bev_gather(key, (256, 200), CARLA_BEV, turned)
        assert (gather.flat is None) == separable
        index = bev_gather_index(key, (256, 200), CARLA_BEV, turned)
        values = np.append(padded[:256, :200].reshape(-1), padded[256, 200])
        padded[256, :], padded[:, 200] = padded[256, 200], padded[256, 200]  # one fill value, as the transform pads
        np.testing.assert_array_equal(gather(padded), values[index])


def test_lidar_raster_equals_the_saturated_histogram() -> None:
    rng = np.random.default_rng(2)
    points = np.vstack([rng.uniform([-40, -50, -2, 0], [70, 50, 3, 1], (5000, 4)), np.tile([[3.1, 2.2, 0, 0]], (9, 1))])
    expected = reference_lidar(points.astype(np.float32), CARLA_BEV)
    got = rasterize_lidar(points.astype(np.float32), CARLA_BEV)
    assert got.dtype == np.uint8 and got.max() == LIDAR_HITS_MAX  # hit counts, scaled by the backbone
    scaled = lidar_input(torch.from_numpy(got), torch.float32)
    assert expected.dtype == np.float32 and expected.max() == 1.0
    np.testing.assert_array_equal(scaled.numpy(), expected)  # bit-identical to LEAD's float32 min(k, 5) / 5


def numpy_lidar_raster(points: np.ndarray, grid: BEVGrid, x_shift: float) -> np.ndarray:
    """The raster as numpy's passes built it before the compiled count: the cell index formed in the points' dtype."""
    h, w = grid.shape
    with np.errstate(over="ignore", invalid="ignore"):
        rows = ((points[:, 0] - points.dtype.type(x_shift)) - grid.x_min) * grid.pixels_per_meter
        cols = (points[:, 1] - grid.y_min) * grid.pixels_per_meter
        inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        cells = np.trunc(rows) * w + np.trunc(cols)
    counts = np.bincount(cells[inside].astype(np.intp), minlength=h * w).reshape(h, w)
    return np.minimum(counts, LIDAR_HITS_MAX).astype(np.uint8)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("x_shift", [0.0, 1.3716])
def test_compiled_lidar_count_equals_numpys_passes(dtype: type, x_shift: float) -> None:
    rng = np.random.default_rng(5)
    points = rng.uniform([-40, -50, -3, 0], [70, 50, 3, 1], (60_000, 4)).astype(dtype)
    points[:20_000, :2] = np.round(points[:20_000, :2] * 4) / 4  # on cell edges, the grids' borders among them
    shifted = points[:20_000:2, 0] + dtype(x_shift)  # on them once shifted, or a float either side
    points[:20_000:2, 0] = np.nextafter(shifted, shifted + np.sign(rng.uniform(-1, 1, len(shifted))).astype(dtype))
    points[:100:7, 0], points[1:100:7, 1], points[2:100:7, 0] = np.nan, np.inf, -np.inf
    points[3000:3300, :2] = [2.1, -3.3]  # one cell, past saturation
    for grid in (CARLA_BEV, NAVSIM_BEV):
        np.testing.assert_array_equal(rasterize_lidar(points, grid, x_shift), numpy_lidar_raster(points, grid, x_shift))


def test_lidar_counts_scale_to_the_float32_levels_of_the_old_raster() -> None:
    counts = torch.arange(LIDAR_HITS_MAX + 1, dtype=torch.uint8)
    old = (np.minimum(np.arange(9), 5) / 5.0).astype(np.float32)[: LIDAR_HITS_MAX + 1]
    np.testing.assert_array_equal(lidar_input(counts, torch.float32).numpy(), old)
    np.testing.assert_array_equal(old, np.float32([0.0, 0.2, 0.4, 0.6, 0.8, 1.0]))
    assert lidar_input(torch.from_numpy(old), torch.float32).equal(torch.from_numpy(old))  # floats pass as they are


def test_carla_camera_and_perspective_labels_equal_the_full_decode(carla_samples: list[dict]) -> None:
    transform = SourceTransform("carla", sensor_spec())  # paper size: the 1152x384 mosaic is the input
    for sample in carla_samples:
        expected = reference_camera(transform, sample)
        got = transform(sample)
        assert set(expected) == {"rgb", "semantic", "depth"}
        assert got["rgb"].dtype == got["semantic"].dtype == got["lidar_bev"].dtype == torch.uint8
        assert got["depth"].shape == (96, 288)  # as stored (1/4): the loss resizes it on the device
        got["depth"] = on_image_grid(got["depth"][None], (384, 1152))[0]
        got["semantic"] = class_ids(got["semantic"])
        assert got["rgb"].permute(1, 2, 0).is_contiguous()  # a view of the decoder's (H, W, 3) pixels, not a copy
        for name, value in expected.items():
            assert name == "rgb" or got[name].is_contiguous(), name
            np.testing.assert_allclose(got[name].numpy(), value, rtol=1e-6, atol=1e-5, err_msg=name)
            if name != "depth":
                np.testing.assert_array_equal(got[name].numpy(), value, err_msg=name)


def test_a_letterboxed_rig_equals_the_full_decode(carla_samples: list[dict]) -> None:
    transform = SourceTransform("carla", sensor_spec(image_size=(256, 1024)))  # 3:1 strip into 4:1: letterboxed
    with pytest.warns(UserWarning, match="letterboxed"):
        got = transform(carla_samples[0])
    expected = reference_camera(transform, carla_samples[0])
    got["semantic"] = class_ids(got["semantic"])
    assert (expected["semantic"] == -1).any()  # the letterbox's padding carries no label
    for name, value in expected.items():
        np.testing.assert_array_equal(got[name].numpy(), value, err_msg=name)


def test_the_transform_reads_only_its_fields_and_gives_the_same_tensors(carla_samples: list[dict]) -> None:
    transform = SourceTransform("carla", sensor_spec())
    assert "past" not in transform.fields and "agents_future" not in transform.fields
    for sample in carla_samples:
        assert {"past", "agents_future"} <= set(sample)  # the adapter wrote them; the model reads neither
        narrow = {k: v for k, v in sample.items() if k in {*transform.fields, "meta", "__key__"}}
        full, fast = transform(sample), transform(narrow)
        assert set(full) == set(fast)
        for name, value in full.items():
            if isinstance(value, torch.Tensor):
                assert torch.equal(value, fast[name]), name


def smooth_camera_sample(width: int, height: int) -> dict:
    """One calibrated camera of ``width`` x ``height`` showing a smooth scene (gradients and soft blobs)."""
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:height, 0:width] / max(width, height)
    image = np.stack([128 + 100 * np.sin(6 * x + 3 * y), 128 + 100 * np.cos(4 * y - 2 * x), 255 * x], axis=2)
    image = cv2.GaussianBlur(image + rng.normal(0, 20, image.shape), (0, 0), 4).clip(0, 255).astype(np.uint8)
    camera = {
        "id": "front",
        "width": width,
        "height": height,
        "K": [[width, 0, width / 2], [0, width, height / 2], [0, 0, 1]],
    }
    meta = {"cameras": [camera]}
    return {"__key__": "k", "meta": meta, "cam_front": cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1]}


@pytest.mark.filterwarnings("ignore:source 'navsim'.*letterboxed")
@pytest.mark.parametrize(
    ("image_size", "factor"),
    [((270, 480), 4), ((540, 960), 2), ((135, 240), 8), ((720, 1280), 1), ((200, 480), 4)],  # the last letterboxed
)
def test_reduced_jpeg_decoding_stays_within_tolerance(image_size: tuple[int, int], factor: int) -> None:
    sample = smooth_camera_sample(1920, 1080)
    transform = SourceTransform("navsim", sensor_spec(image_size=image_size), ["front"])
    layout = transform.camera.plan_for(sample["meta"], [(1080, 1920)]).layout
    assert jpeg_reduction(layout)[0] == factor
    rgb, _ = camera_image(transform, sample)
    expected = reference_camera(transform, sample)["rgb"]
    assert rgb.shape == expected.shape == (3, *image_size)
    diff = np.abs(rgb.numpy().astype(np.int16) - expected)
    assert diff.mean() <= 0.5 and diff.max() <= 4, (diff.mean(), diff.max())
    if factor == 1:
        assert diff.max() == 0


@pytest.mark.filterwarnings("ignore:source 'carla'.*letterboxed")
@pytest.mark.parametrize("image_size", [(270, 480), (200, 480)])
def test_labels_of_a_reduced_decode_follow_the_full_size_layout(image_size: tuple[int, int]) -> None:
    sample = smooth_camera_sample(1920, 1080)
    rng = np.random.default_rng(4)
    sample["semantic_front"] = np.kron(rng.integers(0, 20, (27, 48)), np.ones((40, 40))).astype(np.uint8)
    sample["depth_front"] = rng.integers(0, 256, (270, 480)).astype(np.uint8)  # stored at 1/4, like LEAD's
    sample["meta"]["depth"] = {"max_m": 50.0}
    transform = SourceTransform("carla", sensor_spec(image_size=image_size), ["front"])
    _, layout = camera_image(transform, sample)
    assert jpeg_reduction(layout)[0] == 4
    got = transform.perspective_labels(sample, "carla", layout)
    expected = reference_camera(transform, sample)
    got["semantic"] = class_ids(got["semantic"])
    assert (expected["semantic"] == -1).any() == (image_size == (200, 480))  # letterbox padding: no label
    for name in ("semantic", "depth"):
        np.testing.assert_array_equal(got[name].numpy(), expected[name], err_msg=name)


def test_ltfv6_on_four_navsim_cameras_decodes_at_a_quarter() -> None:
    camera = ((1080, 1920), (Tile(0, 1920, 1545.0, 540.0),))
    layout = camera_layout((camera,) * 4, (270, 1920), NAVSIM_VERTICAL_FOV_DEG)
    assert jpeg_reduction(layout) == (4, cv2.IMREAD_REDUCED_COLOR_4 & ~cv2.IMREAD_COLOR)


def reference_footprints(boxes: np.ndarray, grid: BEVGrid) -> np.ndarray:
    """LEAD's footprint corners box by box, as LEAD computes them: ``cv2.boxPoints`` of numpy scalars."""
    centre, half = footprint_rects(boxes, grid)
    ppm = grid.pixels_per_meter
    corners = np.zeros((len(boxes), 4, 2), np.int32)
    for i, ((cx, cy), (hx, hy), yaw) in enumerate(zip(centre, half, boxes[:, 6], strict=True)):
        rect = ((float(cx), float(cy)), (float(hx * 2 * ppm), float(hy * 2 * ppm)), float(np.rad2deg(-yaw)))
        corners[i] = cv2.boxPoints(rect).astype(np.int32)
    return corners - canvas_crop(grid)


def test_box_points_are_opencvs_bit_for_bit() -> None:
    rng = np.random.default_rng(5)
    count = 20_000
    centres = rng.uniform(-50, 1100, (count, 2))
    sizes = rng.uniform(0, 80, (count, 2))
    angles = np.rad2deg(-rng.uniform(-7, 7, count))
    centres[:2000], sizes[:2000] = np.round(centres[:2000]), np.round(sizes[:2000] * 4) / 4  # on pixel edges
    angles[:1000] = rng.choice([0.0, 90.0, -90.0, 180.0, -180.0, 45.0, 270.0, -0.0], 1000)  # exact quarter turns
    rects = zip(centres.tolist(), sizes.tolist(), angles.tolist(), strict=True)
    expected = np.stack([cv2.boxPoints(rect) for rect in rects])
    np.testing.assert_array_equal(box_points(centres, sizes, angles), expected)


@pytest.mark.parametrize("grid", [CARLA_BEV, NAVSIM_BEV])
def test_footprints_and_the_bev_remap_are_leads_box_by_box_and_numpys(grid: BEVGrid) -> None:
    rng = np.random.default_rng(11)
    boxes = random_boxes(rng, 400).astype(np.float64)
    boxes[:, 9] = rng.integers(0, len(BoxClass), 400)
    np.testing.assert_array_equal(_footprint_pixels(boxes, grid), reference_footprints(boxes, grid))
    hdmap = rng.integers(0, 256, grid.shape).astype(np.uint8)
    for leaderboard in (True, False):
        _, lookup, _ = _bev_tables(leaderboard)
        no_boxes = lead_bev_labels(hdmap, boxes[:0], grid, leaderboard, np.zeros(0, np.int64))
        np.testing.assert_array_equal(no_boxes, lookup[hdmap])  # the LUT and both quarter turns: numpy's gather


def every_footprint_filled(canvas: np.ndarray, boxes: np.ndarray, grid: BEVGrid, leaderboard: bool) -> np.ndarray:
    """The boxes drawn as LEAD's loop draws them (no traffic lights affecting the ego): every footprint on the
    occupancy canvas filled in order, off the grid or not, then the quarter turn."""
    convert, _, bev_class = _bev_tables(leaderboard)
    for box in boxes:
        label = bev_class[int(box[9])] if 0 <= box[9] < len(BoxClass) else LeadBevClass.UNLABELED
        if label != LeadBevClass.UNLABELED and _on_occupancy_canvas(box[None], grid)[0]:
            cv2.fillPoly(canvas, [_footprint_pixels(box[None], grid)[0]], int(convert[label]))
    return cv2.rotate(canvas, cv2.ROTATE_90_CLOCKWISE)


@pytest.mark.parametrize("grid", [CARLA_BEV, NAVSIM_BEV])
def test_footprints_off_the_grid_are_skipped_and_the_drawing_is_the_per_box_loops(grid: BEVGrid) -> None:
    rng = np.random.default_rng(12)
    boxes = random_boxes(rng, 300).astype(np.float64)
    boxes[:100, :2] = rng.uniform(-140, 140, (100, 2))  # far off the grid, some off LEAD's 256 m canvas
    half_pixel = 0.5 / grid.pixels_per_meter  # tiny boxes in the pixels just inside and just outside each edge
    along_x, along_y = rng.uniform(grid.x_min, grid.x_max, 100), rng.uniform(grid.y_min, grid.y_max, 100)
    boxes[100:200, :2] = np.concatenate(
        [
            np.stack([np.full(25, edge + side * half_pixel), along_y[:25]], 1)
            if axis == 0
            else np.stack([along_x[:25], np.full(25, edge + side * half_pixel)], 1)
            for axis, edge, side in ((0, grid.x_min, 1), (0, grid.x_max, -1), (1, grid.y_min, 1), (1, grid.y_max, -1))
        ]
    )
    boxes[100:200, 3:5], boxes[100:200, 6] = 0.05, 0.0
    boxes[200:300:2, :2] = boxes[100:200:2, :2] - np.sign(boxes[100:200:2, :2]) * 2 * half_pixel  # one pixel outside
    boxes[:, 9] = rng.integers(-1, len(BoxClass) + 1, 300)
    boxes[100:, 9] = BoxClass.VEHICLE  # drawn, and not grown as pedestrians are
    hdmap = rng.integers(0, 256, grid.shape).astype(np.uint8)
    for leaderboard in (True, False):
        canvas = cv2.rotate(cv2.LUT(hdmap, _bev_tables(leaderboard)[1]), cv2.ROTATE_90_COUNTERCLOCKWISE)
        got = draw_lead_boxes(canvas.copy(), boxes, grid, leaderboard, np.full(300, -1))
        np.testing.assert_array_equal(got, every_footprint_filled(canvas, boxes, grid, leaderboard))
