"""Models: the one TransFuser family's variants (builders, parameter counts, forward/backward on every source each
reads), the camera crop and LiDAR input, the ego MLP, and the losses' exact maths."""

import math

import pytest
import torch
from batches import random_batch
from hypothesis import given, settings
from hypothesis import strategies as st
from tiny_models import TINY

from lead_s2r.models.config import EgoMLPConfig, default_grids
from lead_s2r.models.ego_mlp import EgoStatusMLP
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_config import TARGET_SPEED_CLASSES, LeadConfig
from lead_s2r.models.lead_driver import VARIANTS, CameraSelect, LeadDriver, ltfv6_navsim, tfv6
from lead_s2r.models.lead_loss import two_hot
from lead_s2r.training.losses import heading_loss, lead_semantic_loss, radar_loss

#: variant -> (builder overrides, the sources its network reads)
CASES = {
    "tfv6": ({}, ("carla",)),
    "tfv5": ({}, ("carla",)),
    "ltfv6_navsim": ({"use_carla_data": True}, ("navsim", "carla")),
    "ltfv6_wod": ({}, ("wod",)),
}

pytestmark = pytest.mark.usefixtures("one_thread")


def count_parameters(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def test_every_variant_is_a_documented_builder_of_the_one_family():
    assert set(VARIANTS) == set(CASES)
    for name, build in VARIANTS.items():
        assert build.__doc__ and build.__name__ == name
        driver = build(**TINY)
        assert isinstance(driver, LeadDriver) and isinstance(driver.config, LeadConfig)
    assert tfv6(**TINY).config.use_tp and not ltfv6_navsim(**TINY).config.use_tp


def test_parameter_counts_at_paper_size():
    counts = {name: count_parameters(build()) for name, build in VARIANTS.items()}
    counts["ego_mlp"] = count_parameters(EgoStatusMLP(EgoMLPConfig()))
    # LEAD README: "ResNet34 (60M params)"; docs/models.md lists LEAD's exact counts (tests/test_lead_checkpoints.py)
    assert 50e6 < counts["tfv6"] < 70e6
    assert counts["ltfv6_navsim"] < counts["tfv6"]  # no radar branch, a 2-channel BEV input
    assert counts["ego_mlp"] < 1e6


@pytest.mark.parametrize("variant", sorted(CASES))
def test_forward_backward_on_every_source_the_variant_reads(variant):
    overrides, sources = CASES[variant]
    driver = VARIANTS[variant](**TINY, **overrides)
    assert tuple(driver.config.sources) == sources
    for source in sources:
        batch = random_batch(driver, 2, source)
        out = driver(batch, source)
        grid = driver.grid(source)
        assert out["waypoints"].shape == (2, grid.num_points, 2)
        assert ("headings" in out) == variant.startswith("ltfv6_navsim")
        assert ("route" in out) == (variant in ("tfv6", "tfv5"))
        if variant == "ltfv6_wod":
            assert driver.tasks(source) == {"waypoints"}
        sum(v.float().mean() for v in out.values()).backward()
        grads = [p.grad for p in driver.network.parameters() if p.grad is not None]
        assert grads and all(torch.isfinite(g).all() for g in grads)
        driver.zero_grad()


def test_camera_select_keeps_the_used_tiles_in_order():
    mosaic = torch.arange(6.0).repeat_interleave(4).expand(1, 3, 2, 24)  # each pixel holds its tile's id
    assert torch.equal(CameraSelect(6, (1, 2, 4))(mosaic)[0, 0, 0, ::4], torch.tensor([1.0, 2.0, 4.0]))
    assert CameraSelect(6, None)(mosaic) is mosaic
    with pytest.raises(ValueError, match="must index the 6 camera tiles"):
        CameraSelect(6, (6,))


def test_uint8_lidar_counts_give_the_outputs_of_the_float_raster():
    """The loader ships hit counts (uint8, 0..5); the network must see LEAD's float32 raster ``min(k, 5) / 5``."""
    driver = tfv6(**TINY).eval()
    batch = random_batch(driver, 2, "carla")
    counts = batch["lidar_bev"]
    floats = torch.from_numpy(counts.numpy().astype("float64") / 5.0).float()
    with torch.no_grad():
        out_counts = driver(dict(batch, lidar_bev=counts), "carla")
        out_floats = driver(dict(batch, lidar_bev=floats), "carla")
    assert counts.max() == 5 and set(out_counts) == set(out_floats)
    for name, value in out_floats.items():
        assert torch.equal(out_counts[name], value), name


def test_ltfv6_reads_no_lidar():
    driver = ltfv6_navsim(**TINY)
    assert not input_spec(driver.config).lidar_raster and "lidar_bev" not in random_batch(driver, 1, "navsim")


@settings(max_examples=50, deadline=None)
@given(st.floats(-5.0, 30.0))
def test_two_hot_decodes_to_the_clamped_value(speed):
    classes = torch.tensor(TARGET_SPEED_CLASSES)
    encoded = two_hot(torch.tensor([speed]), torch.tensor([False]), classes)
    assert encoded.sum().item() == pytest.approx(1.0)
    assert (encoded > 0).sum() <= 2
    assert (encoded * classes).sum().item() == pytest.approx(min(max(speed, 0.0), 20.0), abs=1e-4)


def test_heading_loss_follows_targets_through_pi_and_charges_a_full_turn():
    """A U-turn whose target crosses +-pi (stored wrapped) is matched by continuous headings; a prediction a full
    turn off is not free (with a wrapped error it was, and cumulative headings spun through 2 pi)."""
    batch = {"headings": torch.tensor([[1.5, 3.0, -3.1, -2.9]])}
    continuous = torch.tensor([[1.5, 3.0, 2 * math.pi - 3.1, 2 * math.pi - 2.9]])
    assert heading_loss({"headings": continuous}, batch).item() == pytest.approx(0.0, abs=1e-6)
    assert heading_loss({"headings": batch["headings"]}, batch).item() == pytest.approx(math.pi, abs=1e-5)
    straight = {"headings": torch.zeros(1, 4)}
    spun = {"headings": torch.tensor([[0.0, 0.0, 2 * math.pi, 2 * math.pi]])}
    assert heading_loss(spun, straight).item() == pytest.approx(math.pi, abs=1e-5)


def test_radar_loss_is_permutation_invariant_and_zero_l1_on_perfect_match():
    targets = torch.tensor([[[10.0, 2.0, 5.0], [-3.0, 4.0, 1.0]]])
    pred = {
        "radar_xy": targets[:, [1, 0], :2].clone(),
        "radar_speed": targets[:, [1, 0], 2].clone(),
        "radar_logit": torch.full((1, 2), 20.0),
    }
    batch = {"radar_targets": targets, "radar_targets_valid": torch.ones(1, 2, dtype=torch.bool)}
    assert radar_loss(pred, batch, (40.0, 40.0, 20.0)).item() == pytest.approx(0.0, abs=1e-6)
    pred["radar_xy"] = pred["radar_xy"] + torch.tensor([4.0, 0.0])  # 4 m off in x on both = 0.1 scaled
    assert radar_loss(pred, batch, (40.0, 40.0, 20.0)).item() == pytest.approx(5 * 0.1, abs=1e-5)


def test_radar_loss_matches_within_each_sample_of_a_batch():
    """Sample 0 has no object; sample 1 has two, in slots 0 and 2 (slot 1 is padding holding junk). LEAD averages the
    per-sample losses: sample 0 adds 0, sample 1 its 5 x 0.1."""
    targets = torch.tensor([[[0.0, 0.0, 0.0]] * 3, [[10.0, 2.0, 5.0], [99.0, 99.0, 9.0], [-3.0, 4.0, 1.0]]])
    valid = torch.tensor([[False, False, False], [True, False, True]])
    pred = {
        "radar_xy": torch.stack([targets[1, [2, 0], :2], targets[1, [2, 0], :2]]) + torch.tensor([4.0, 0.0]),
        "radar_speed": torch.stack([targets[1, [2, 0], 2]] * 2),
        "radar_logit": torch.tensor([[-20.0, -20.0], [20.0, 20.0]]),
    }
    batch = {"radar_targets": targets, "radar_targets_valid": valid}
    assert radar_loss(pred, batch, (40.0, 40.0, 20.0)).item() == pytest.approx(5 * 0.1 / 2, abs=1e-5)


def test_semantic_loss_is_the_mean_over_every_pixel_of_a_labelled_sample():
    """LEAD's perspective term: unlabelled pixels add 0 but count; a sample without any label is left out."""
    logits = torch.zeros(2, 4, 2, 2, requires_grad=True)  # uniform: log 4 per labelled pixel
    labels = torch.tensor([[[0, 255], [3, 255]], [[255, 255], [255, 255]]], dtype=torch.uint8)  # the loader's
    assert lead_semantic_loss(logits, labels).item() == pytest.approx(math.log(4) / 2)
    unlabelled = lead_semantic_loss(logits, torch.full((2, 2, 2), 255, dtype=torch.uint8))
    assert unlabelled.item() == 0.0 and unlabelled.requires_grad


def test_ego_mlp_outputs_every_grid():
    model = EgoStatusMLP(EgoMLPConfig(hidden=16))
    driver = tfv6(**TINY)
    for source, grid in default_grids().items():
        out = model(random_batch(driver, 3, "carla"), source)
        assert out["waypoints"].shape == (3, grid.num_points, 2)
        assert out["headings"].shape == (3, grid.num_points)
