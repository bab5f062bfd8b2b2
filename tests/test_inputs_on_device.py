"""Inputs left raw by the loader (camera JPEGs, LiDAR points) and built on the training device give the loader's
own tensors.

On the CPU both decodes are libjpeg-turbo's and both rasters the same float32 arithmetic, so everything downstream
of a JPEG that is the model's image as stored (one camera at ``image_size``) must be bit-identical. Rigs the device
lays out (crop, stitch, scale: WOD-E2E's three cameras, NAVSIM's four) are held to a full decode and OpenCV's
``INTER_AREA`` within a level or two on smooth images, and to the loader's reduced decode within what that decode
moves.
"""

import math
from types import SimpleNamespace
from typing import Any

import cv2
import lightning as L
import numpy as np
import pytest
import torch
from tiny_models import TINY, sensor_spec

from lead_s2r.convert import convert
from lead_s2r.data.camera_layout import CameraLayout, Tile, camera_layout, render
from lead_s2r.data.collate import collate
from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.data.device_inputs import (
    LIDAR_POINTS,
    RGB_JPEG,
    RGB_LAYOUT,
    area_weights,
    check_device_decode,
    decode_images,
    decode_rgb,
    jpeg_tensor,
    on_device_layout,
    rasterize_points,
)
from lead_s2r.data.lidar import lidar_xy, rasterize_lidar
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.data.transforms import SourceTransform
from lead_s2r.models.config import BEVGrid
from lead_s2r.models.input_spec import InputSpec, input_spec
from lead_s2r.models.inputs import LIDAR_HITS_MAX
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_driver import tfv6
from lead_s2r.registry import get_adapter
from lead_s2r.shards import read_samples
from lead_s2r.synthetic import wod_e2e
from lead_s2r.synthetic.carla_lead import generate
from lead_s2r.training.module import DrivingModule


def assert_batches_equal(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for name, value in a.items():
        if isinstance(value, torch.Tensor):
            assert value.dtype == b[name].dtype and torch.equal(value, b[name]), name
        else:
            assert value == b[name], name


@pytest.mark.parametrize("quality", [75, 95])
@pytest.mark.parametrize("gray", [False, True])
def test_libjpeg_turbo_through_torch_decodes_what_opencv_decodes(quality: int, gray: bool) -> None:
    rng = np.random.default_rng(quality)
    image = rng.integers(0, 256, (96, 160) if gray else (96, 160, 3), dtype=np.uint8)  # noise: every coefficient
    data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()
    ours = decode_rgb([jpeg_tensor(data)], "cpu")[0]
    opencv = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR_RGB)
    assert ours.shape == (3, 96, 160)
    np.testing.assert_array_equal(ours.permute(1, 2, 0).numpy(), opencv)


def on_the_device(batch: dict, config: InputSpec) -> dict:
    """What the data module does before the batch moves, on the CPU."""
    return rasterize_points(decode_images(batch, "cpu"), config.bev, "cpu")


def test_inputs_sent_raw_give_the_loaders_batch(carla_samples: list[dict]) -> None:
    config = sensor_spec()  # paper size: the 1152x384 mosaic is the model's image as stored
    in_loader = collate([SourceTransform("carla", config)(sample) for sample in carla_samples])
    encoded = collate([SourceTransform("carla", config, inputs_on_device=True)(sample) for sample in carla_samples])
    assert "rgb" not in encoded and len(encoded[RGB_JPEG]) == len(carla_samples)
    assert "lidar_bev" not in encoded and [len(p) for p in encoded[LIDAR_POINTS]] == [
        len(sample["lidar"]) for sample in carla_samples
    ]
    assert bytes(encoded[RGB_JPEG][0][0].numpy()) == bytes(carla_samples[0]["cam_carla_mosaic"])
    assert in_loader["rgb"].is_contiguous(memory_format=torch.channels_last)
    assert_batches_equal(on_the_device(encoded, config), in_loader)


def test_the_device_raster_is_the_loaders_on_cell_edges_and_off_the_grid() -> None:
    grid = BEVGrid(-8.0, 8.0, -4.0, 4.0, 2.0)  # 32 x 16 cells of 0.5 m
    rng = np.random.default_rng(0)
    edges = np.stack(np.meshgrid(np.arange(-8.5, 8.75, 0.25), np.arange(-4.5, 4.75, 0.25)), -1).reshape(-1, 2)
    clouds = [
        np.concatenate([edges, rng.uniform(-9, 9, (500, 2))]).astype(np.float32),  # every edge, inside and out
        np.float32([[np.nan, 0.0], [0.0, np.inf], [np.nextafter(np.float32(8), 0), 3.99], [8.0, 0.0]]),
        np.zeros((0, 2), np.float32),
        np.repeat(np.float32([[0.1, 0.1]]), 9, axis=0),  # saturates at LIDAR_HITS_MAX
    ]
    batch = rasterize_points({LIDAR_POINTS: [lidar_xy(c) for c in clouds]}, grid, "cpu")
    expected = np.stack([rasterize_lidar(c, grid) for c in clouds])[:, None]
    np.testing.assert_array_equal(batch["lidar_bev"].numpy(), expected)
    assert batch["lidar_bev"][3].max() == LIDAR_HITS_MAX and expected.sum() > 0


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_points_moved_in_the_raster_and_their_xy_are_the_moved_clouds(dtype: type) -> None:
    grid = BEVGrid(-8.0, 8.0, -4.0, 4.0, 2.0)
    rng = np.random.default_rng(1)
    cloud = rng.uniform(-9, 9, (2000, 4)).astype(dtype)
    cloud[:3, :2] = [[np.nan, 0.0], [-0.0, np.inf], [1.389, -0.0]]
    shift = 1.389
    for points in (cloud, cloud[::3], cloud[::-1], np.asfortranarray(cloud), cloud[:, :2], cloud[:, 1:]):
        moved = points.copy()
        moved[:, 0] -= dtype(shift)  # what to_centre_origin does to every other point field
        np.testing.assert_array_equal(rasterize_lidar(points, grid, shift), rasterize_lidar(moved, grid))
        for x_shift, expected in ((0.0, points), (shift, moved)):
            xy = lidar_xy(points, x_shift).numpy()
            assert xy.flags.c_contiguous and xy.dtype == dtype and not np.shares_memory(xy, points)
            assert xy.tobytes() == np.ascontiguousarray(expected[:, :2]).tobytes()  # NaN and -0.0 too


def test_a_rig_the_device_would_enlarge_is_laid_out_in_the_loader(carla_samples: list[dict]) -> None:
    config = sensor_spec(image_size=(768, 2304))  # OpenCV's INTER_AREA interpolates when it enlarges: not area weights
    out = SourceTransform("carla", config, inputs_on_device=True)(carla_samples[0])
    assert RGB_JPEG not in out and out["rgb"].shape == (3, 768, 2304)
    assert torch.equal(out["rgb"], SourceTransform("carla", config)(carla_samples[0])["rgb"])


def test_a_scaled_mosaic_goes_to_the_device_and_comes_back_as_the_full_decodes_area_resize(
    carla_samples: list[dict],
) -> None:
    config = sensor_spec(image_size=(192, 576))  # the mosaic at half size: the loader decodes it reduced
    out = SourceTransform("carla", config, inputs_on_device=True)(carla_samples[0])
    assert "rgb" not in out and len(out[RGB_JPEG]) == 1 and out[RGB_LAYOUT].image_size == (192, 576)
    rgb = on_the_device(collate([out]), config)["rgb"][0]
    full = cv2.imdecode(np.frombuffer(carla_samples[0]["cam_carla_mosaic"], np.uint8), cv2.IMREAD_COLOR_RGB)
    reference = cv2.resize(full, (576, 192), interpolation=cv2.INTER_AREA)
    assert rgb.dtype == torch.uint8 and rgb.shape == (3, 192, 576)
    assert np.abs(rgb.permute(1, 2, 0).numpy().astype(int) - reference).max() <= 1  # rounding of the 2x2 means


def test_a_batch_mixing_encoded_and_decoded_images_is_decoded_in_the_loader(carla_samples: list[dict]) -> None:
    config = sensor_spec()
    loader, device = (
        SourceTransform("carla", config),
        SourceTransform("carla", config, inputs_on_device=True),
    )
    laid_out = {k: v for k, v in device(carla_samples[0]).items() if k not in (RGB_JPEG, RGB_LAYOUT)}  # in the loader
    laid_out["rgb"] = loader(carla_samples[0])["rgb"]
    mixed = collate([laid_out, device(carla_samples[1]), device(carla_samples[2])])
    assert RGB_JPEG not in mixed
    assert_batches_equal(on_the_device(mixed, config), collate([loader(sample) for sample in carla_samples]))


def test_a_device_decode_is_held_to_the_cpus(carla_samples: list[dict]) -> None:
    encoded = [jpeg_tensor(carla_samples[0]["cam_carla_mosaic"])]
    pixels = decode_rgb(encoded, "cpu")[0]
    layout = camera_layout((((384, 1152), (Tile(0, 1152),)),), (384, 1152), None)
    assert check_device_decode(encoded, layout, pixels) == 0.0
    nudged = pixels.clone()
    nudged[:, ::2] ^= 1  # nvJPEG-like rounding: half the rows one level off
    assert check_device_decode(encoded, layout, nudged) == pytest.approx(0.5, abs=0.01)
    with pytest.raises(RuntimeError, match="inputs_on_device=false"):
        check_device_decode(encoded, layout, pixels.flip(-1))  # a decoder that mirrors the image


def test_a_jpeg_of_another_size_than_its_layouts_names_its_sample() -> None:
    jpegs = [cv2.imencode(".jpg", np.zeros((h, 32, 3), np.uint8))[1].tobytes() for h in (16, 24)]
    layout = camera_layout((((16, 32), (Tile(0, 32),)),), (16, 32), None)
    batch = {"__key__": ["a/1", "b/2"], RGB_JPEG: [[jpeg_tensor(data)] for data in jpegs], RGB_LAYOUT: [layout] * 2}
    with pytest.raises(ValueError, match=r"sample b/2: its camera JPEGs decode to \[\(24, 32\)\]"):
        decode_images(batch, "cpu")


def test_an_undecodable_jpeg_names_the_batchs_samples() -> None:
    good = cv2.imencode(".jpg", np.zeros((16, 32, 3), np.uint8))[1].tobytes()
    layout = camera_layout((((16, 32), (Tile(0, 32),)),), (16, 32), None)
    batch = {
        "__key__": ["a/1", "b/2"],
        RGB_JPEG: [[jpeg_tensor(good)], [jpeg_tensor(good[: len(good) // 3])]],
        RGB_LAYOUT: [layout] * 2,
    }
    with pytest.raises(ValueError, match=r"samples \['a/1', 'b/2'\] is not decodable"):
        decode_images(batch, "cpu")


def test_the_data_module_decodes_before_the_batch_moves(carla_samples: list[dict], toy_data: str) -> None:
    config = sensor_spec()
    encoded = collate([SourceTransform("carla", config, inputs_on_device=True)(sample) for sample in carla_samples])
    dm = DriveDataModule(train={"carla": SourceSpec([toy_data])}, inputs=config)
    dm.trainer = SimpleNamespace(strategy=SimpleNamespace(root_device=torch.device("cpu")))
    batch = dm.on_before_batch_transfer({"carla": encoded}, 0)
    assert RGB_JPEG not in batch["carla"] and LIDAR_POINTS not in batch["carla"]
    in_loader = collate([SourceTransform("carla", config)(sample) for sample in carla_samples])
    assert_batches_equal(batch["carla"], in_loader)


@pytest.fixture(scope="module")
def converted_route(tmp_path_factory: pytest.TempPathFactory) -> str:
    root = tmp_path_factory.mktemp("route")
    generate(root / "raw", count=1, seed=5, frames=4)
    convert(get_adapter("carla_lead"), root / "raw", root / "data")
    return str(root / "data")


def carla_data(path: str, config: InputSpec, **kwargs: Any) -> DriveDataModule:
    schedule = MixingSchedule.constant({"carla": 1.0}, 2)
    dm = DriveDataModule(train={"carla": SourceSpec([path])}, schedule=schedule, inputs=config, **kwargs)
    dm.trainer = SimpleNamespace(current_epoch=0, world_size=1)
    return dm


def test_a_loader_worker_sends_the_raw_inputs_to_the_main_process(converted_route: str) -> None:
    batches = {}
    for workers, to_device in ((1, True), (0, False)):
        dm = carla_data(
            converted_route, sensor_spec(), steps_per_epoch=2, num_workers=workers, inputs_on_device=to_device
        )
        batches[to_device] = list(dm.train_dataloader()["carla"])  # seeded: the same samples in the same order
    for encoded, decoded in zip(batches[True], batches[False], strict=True):
        assert len(encoded[RGB_JPEG]) == 2 and encoded["__key__"] == decoded["__key__"]
        assert_batches_equal(on_the_device(encoded, sensor_spec()), decoded)


def test_lightning_decodes_them_before_the_forward(converted_route: str) -> None:
    driver = tfv6(**{**TINY, "camera_tile_size": None})  # LEAD's 384 x 1152 mosaic, the generated one: sent encoded
    config = input_spec(driver.config)
    dm = carla_data(converted_route, config, steps_per_epoch=1, inputs_on_device=True)
    module = DrivingModule(driver)
    seen: list[tuple[int, ...]] = []
    module.model.register_forward_pre_hook(
        lambda _, args: seen.append((*args[0]["rgb"].shape, *args[0]["lidar_bev"].shape))
    )
    options = {"logger": False, "enable_checkpointing": False, "enable_progress_bar": False, "limit_val_batches": 0}
    fit = L.Trainer(accelerator="cpu", max_steps=1, **options)
    fit.fit(module, datamodule=dm)
    assert seen == [(2, 3, 384, 1152, 2, 1, *config.bev.shape)] and math.isfinite(fit.callback_metrics["train/loss"])


def test_the_datamodule_sends_raw_inputs_only_when_training_on_a_gpu(toy_data: str) -> None:
    def on(dm: DriveDataModule, device: str) -> bool:
        dm.trainer = SimpleNamespace(strategy=SimpleNamespace(root_device=torch.device(device)))
        return dm.inputs_on_device

    train = {"carla": SourceSpec([toy_data])}
    auto = DriveDataModule(train=train, inputs=sensor_spec())
    assert not auto.inputs_on_device  # no trainer yet
    assert not on(auto, "cpu") and on(auto, "cuda")
    assert on(DriveDataModule(train=train, inputs=sensor_spec(), inputs_on_device=True), "cpu")
    assert not on(DriveDataModule(train=train, inputs=sensor_spec(), inputs_on_device=False), "cuda")


def smooth_jpeg(height: int, width: int, seed: int) -> bytes:
    """A smooth colour image (low-frequency waves), q=95: what a camera sees away from edges."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width] / max(height, width)
    channels = [127 + 100 * np.sin(2 * np.pi * (rng.uniform(0.5, 3) * x + rng.uniform(0.5, 3) * y)) for _ in range(3)]
    image = np.clip(np.stack(channels, -1), 0, 255).astype(np.uint8)
    return cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def rig(sizes: list[tuple[int, int]], image_size: tuple[int, int], fov: float | None, cy: float = 0.5) -> CameraLayout:
    """The layout of cameras of ``sizes``, each one tile with fy = its height and cy at ``cy`` of its height."""
    cameras = tuple(((h, w), (Tile(0, w, float(h), cy * h),)) for h, w in sizes)
    return camera_layout(cameras, image_size, fov)


#: Rigs the device lays out: WOD-E2E's three fronts into LTFv6's 972x360 (at half size: the same 1.5x non-integer
#: ratio); a field of view beyond the cameras' (padding rows) letterboxed; cameras of two heights (a band scaled to the
#: strip's height first: two area resizes composed); a NAVSIM-like crop of rows around the principal point.
RIGS = {
    "wod_fronts": rig([(540, 486)] * 3, (360, 972), None),
    "padded_letterboxed": rig([(200, 300), (200, 300)], (120, 600), 80.0, cy=0.3),
    "two_heights": rig([(300, 270), (450, 405), (300, 270)], (100, 270), None),
    "navsim_crop": rig([(270, 480)] * 4, (68, 960), 40.0),
}


@pytest.mark.parametrize("name", RIGS)
def test_the_device_layout_is_a_full_decodes_inter_area_within_a_level_or_two(name: str) -> None:
    layout = RIGS[name]
    assert on_device_layout(layout)
    jpegs = [smooth_jpeg(h, w, seed) for seed, (h, w) in enumerate(layout.sizes)]
    batch = {RGB_JPEG: [[jpeg_tensor(data) for data in jpegs]], RGB_LAYOUT: [layout]}
    rgb = decode_images(batch, "cpu")["rgb"]
    assert rgb.dtype == torch.uint8 and rgb.shape == (1, 3, *layout.image_size)
    full = [cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR_RGB) for data in jpegs]
    reference = render(layout, full, cv2.INTER_AREA, 0).astype(int)
    difference = np.abs(rgb[0].permute(1, 2, 0).numpy().astype(int) - reference)
    assert difference.max() <= 2 and difference.mean() < 0.5, (difference.max(), difference.mean())
    y0, x0 = layout.box[:2]
    assert rgb[0, :, :y0].sum() == 0 and rgb[0, :, :, :x0].sum() == 0  # letterbox padding stays black


def test_a_rig_that_enlarges_does_not_take_the_route() -> None:
    assert not on_device_layout(rig([(100, 300)], (200, 600), None))  # OpenCV interpolates where it enlarges
    assert not on_device_layout(rig([(300, 270), (200, 180)], (100, 450), None))  # the short camera enlarged
    assert on_device_layout(rig([(384, 1152)], (384, 1152), None))  # the model's image as stored


def test_area_weights_are_inter_area_for_non_integer_ratios() -> None:
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (101, 157), dtype=np.uint8)  # noise: any weight off shows
    ours = area_weights(101, 37) @ image.astype(np.float64) @ area_weights(157, 60).T
    np.testing.assert_array_equal(np.round(ours), cv2.resize(image, (60, 37), interpolation=cv2.INTER_AREA))
    np.testing.assert_allclose(area_weights(7, 3).sum(axis=1), 1.0)


@pytest.fixture(scope="module")
def wod_samples(tmp_path_factory: pytest.TempPathFactory) -> list[dict]:
    """Generated WOD-E2E frames with cameras at 0.4 of the real size (389x432: the strip 1.2x LTFv6's image)."""
    root = tmp_path_factory.mktemp("wod")
    wod_e2e.generate(root / "raw", count=1, seed=3, splits={"train": 1}, image_scale=0.4)
    assert convert(get_adapter("wod_e2e"), root / "raw", root / "data").ok
    fields = wod_transform().fields
    return [sample for _, sample in zip(range(3), read_samples(root / "data", fields), strict=False)]


def wod_transform(inputs_on_device: bool = False) -> SourceTransform:
    driver = {"use_waymo_e2e_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True}
    config = input_spec(LeadConfig(**driver))
    return SourceTransform("wod", config, ["front_left", "front", "front_right"], inputs_on_device=inputs_on_device)


def test_wod_cameras_decoded_by_the_module_are_the_loaders_but_for_the_decode_size(wod_samples: list[dict]) -> None:
    loader, device = wod_transform(), wod_transform(inputs_on_device=True)
    in_loader = collate([loader(sample) for sample in wod_samples])
    encoded = collate([device(sample) for sample in wod_samples])
    assert "rgb" not in encoded and [len(jpegs) for jpegs in encoded[RGB_JPEG]] == [3] * len(wod_samples)
    built = on_the_device(encoded, device.spec)
    assert set(built) == set(in_loader)
    assert_batches_equal(
        {k: v for k, v in built.items() if k != "rgb"}, {k: v for k, v in in_loader.items() if k != "rgb"}
    )
    assert built["rgb"].dtype == torch.uint8 and built["rgb"].shape == in_loader["rgb"].shape == (3, 3, 360, 972)
    difference = (built["rgb"].int() - in_loader["rgb"].int()).abs()
    assert difference.float().mean() < 1.0, difference.float().mean()  # the reduced decode's rounding, not a layout


def test_a_mixed_batch_is_laid_out_in_the_loader_as_the_device_would(wod_samples: list[dict]) -> None:
    loader, device = wod_transform(), wod_transform(inputs_on_device=True)
    laid_out = {k: v for k, v in device(wod_samples[0]).items() if k not in (RGB_JPEG, RGB_LAYOUT)}
    laid_out["rgb"] = loader(wod_samples[0])["rgb"]  # a sample whose rig the loader laid out
    mixed = collate([laid_out, *(device(sample) for sample in wod_samples[1:])])
    assert RGB_JPEG not in mixed and RGB_LAYOUT not in mixed
    all_on_device = on_the_device(collate([device(sample) for sample in wod_samples]), device.spec)
    assert torch.equal(mixed["rgb"][0], laid_out["rgb"]) and torch.equal(mixed["rgb"][1:], all_on_device["rgb"][1:])


def test_a_batch_of_several_rigs_lays_out_each_by_its_own() -> None:
    layouts = [RIGS["navsim_crop"], rig([(136, 1920)], (68, 960), None), RIGS["navsim_crop"]]
    encoded = [[jpeg_tensor(smooth_jpeg(h, w, i)) for h, w in layout.sizes] for i, layout in enumerate(layouts)]
    together = decode_images({RGB_JPEG: encoded, RGB_LAYOUT: layouts}, "cpu")["rgb"]
    for jpegs, layout, image in zip(encoded, layouts, together, strict=True):
        assert torch.equal(decode_images({RGB_JPEG: [jpegs], RGB_LAYOUT: [layout]}, "cpu")["rgb"][0], image)
