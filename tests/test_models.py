"""Models: parameter counts, forward/backward of every variant on every source, and the pieces' exact maths."""

import math

import pytest
import torch
from batches import random_batch
from hypothesis import given, settings
from hypothesis import strategies as st
from tiny_models import TINY

from lead_s2r.models.backbone import CameraSelect, StagedEncoder
from lead_s2r.models.config import EgoMLPConfig, ltfv6_config, tfv5_config, tfv6_config
from lead_s2r.models.ego_mlp import EgoStatusMLP
from lead_s2r.models.embeddings import grid_embedding, sine_embedding
from lead_s2r.models.inputs import target_point_range
from lead_s2r.models.lead_loss import two_hot
from lead_s2r.models.planning_decoder import TargetPointNorm
from lead_s2r.models.tfv6 import TFv6, count_parameters
from lead_s2r.training.losses import focal_heatmap_loss, heading_loss, radar_loss, segmentation_loss

SOURCES = ("carla", "navsim", "wod")
VARIANTS = {"tfv6": tfv6_config, "ltfv6": ltfv6_config, "tfv5": tfv5_config}


pytestmark = pytest.mark.usefixtures("one_thread")


def test_parameter_counts_match_lead():
    counts = {name: count_parameters(TFv6(make())) for name, make in VARIANTS.items()}
    counts["ego_mlp"] = count_parameters(EgoStatusMLP(EgoMLPConfig()))
    for name, n in counts.items():
        print(f"{name:8s} {n / 1e6:6.2f}M")
    # LEAD README: "ResNet34 (60M params)" with token dim 256 (two ResNet34 = 42.6M, fusion 8.4M, planner 9.6M)
    assert 55e6 < counts["tfv6"] < 70e6
    assert counts["ltfv6"] < counts["tfv6"]  # no radar branch
    assert counts["ego_mlp"] < 1e6


@pytest.mark.parametrize("variant", sorted(VARIANTS))
@pytest.mark.parametrize("source", SOURCES)
def test_forward_backward(variant, source):
    config = VARIANTS[variant](**TINY)
    model = TFv6(config)
    batch = random_batch(config, 2, source)
    out = model(batch, source)
    grid = config.trajectory_grids[source]
    assert out["waypoints"].shape == (2, grid.num_points, 2)
    assert out["route"].shape == (2, config.num_route_points, 2)
    assert ("headings" in out) == (variant != "tfv5")
    assert set(model.tasks(source)) >= {"waypoints", "route", "target_speed"}
    if source == "carla":
        assert out["bev_semantic"].shape[1] == config.bev_semantic_classes["carla"]
        assert out["box_heatmap"].shape[-2:] == (config.bev.shape[0] // 4, config.bev.shape[1] // 4)
        assert ("radar_xy" in out) == config.use_radar
    if source == "wod":
        assert not model.tasks(source) & {"bev_semantic", "boxes", "depth", "semantic", "radar"}
    sum(v.float().mean() for v in out.values()).backward()
    grads = [p.grad for p in model.planner.parameters() if p.grad is not None]
    assert grads and all(torch.isfinite(g).all() for g in grads)


def test_forward_computes_only_requested_tasks():
    config = tfv6_config(**TINY)
    model = TFv6(config)
    out = model(random_batch(config, 2, "carla"), "carla", {"bev_semantic"})
    assert set(out) == {"bev_semantic"}
    with pytest.raises(ValueError, match="depth"):
        model(random_batch(config, 2, "wod"), "wod", {"depth"})


def test_raster_model_needs_lidar():
    config = tfv6_config(**TINY)
    batch = random_batch(config, 1, "carla")
    del batch["lidar_bev"]
    with pytest.raises(KeyError, match="lidar_bev"):
        TFv6(config)(batch, "carla")


def test_uint8_lidar_counts_give_the_outputs_of_the_float_raster():
    """The loader ships hit counts (uint8, 0..5); the backbone divides by 5 and must see LEAD's float32 raster."""
    config = tfv6_config(**TINY)
    model = TFv6(config).eval()
    batch = random_batch(config, 2, "carla")
    counts = torch.randint(0, 6, batch["lidar_bev"].shape, generator=torch.Generator().manual_seed(0))
    counts = counts.to(torch.uint8)
    floats = torch.from_numpy(counts.numpy().astype("float64") / 5.0).float()  # LEAD: float32(min(k, 5) / 5)
    with torch.no_grad():
        out_counts = model(dict(batch, lidar_bev=counts), "carla")
        out_floats = model(dict(batch, lidar_bev=floats), "carla")
    assert counts.max() == 5 and set(out_counts) == set(out_floats)
    for name, value in out_floats.items():
        assert torch.equal(out_counts[name], value), name


def test_ltfv6_reads_no_lidar_and_latent_option_learns_its_input():
    config = ltfv6_config(**TINY)
    assert "lidar_bev" not in random_batch(config, 1, "navsim")
    latent = TFv6(ltfv6_config(**TINY, bev_input="latent"))
    out = latent(random_batch(config, 1, "navsim"), "navsim", {"waypoints"})
    out["waypoints"].sum().backward()
    assert latent.backbone.bev_latent.grad.abs().sum() > 0


def test_staged_encoder_rejects_unstageable_architecture():
    with pytest.raises(ValueError, match="test_efficientnet"):
        StagedEncoder("test_efficientnet", False, 3)
    with pytest.raises(ValueError, match="'no_such_net' is no timm architecture"):  # a config's typo
        StagedEncoder("no_such_net", False, 3)


def test_staged_encoder_matches_timm_features():
    import timm

    torch.manual_seed(0)
    net = timm.create_model("test_resnet", features_only=True)
    staged = StagedEncoder("test_resnet", False, 3)
    staged.load_state_dict({f"stages.{i}.{k}": v for i, s in enumerate(staged.stages) for k, v in _sub(net, s).items()})
    net.eval(), staged.eval()
    x = torch.rand(1, 3, 64, 64)
    expected = net(x)[-4:]
    got, y = [], x
    for stage in staged.stages:
        y = stage(y)
        got.append(y)
    for e, g in zip(expected, got, strict=True):
        torch.testing.assert_close(e, g)


def _sub(net: torch.nn.Module, stage: torch.nn.Sequential) -> dict[str, torch.Tensor]:
    """The state of ``net``'s modules that ``stage`` holds, keyed as in the stage."""
    state = net.state_dict()
    return {k: state[k] for k in stage.state_dict()}


def test_camera_select_keeps_chosen_tiles_and_fov():
    image = torch.arange(12.0).view(1, 1, 12).expand(1, 2, 12)  # 3 tiles of width 4: [0..3] [4..7] [8..11]
    assert CameraSelect(3, (2, 0), 1.0)(image)[0, 0].tolist() == [8, 9, 10, 11, 0, 1, 2, 3]
    assert CameraSelect(3, None, 0.5)(image)[0, 0].tolist() == [1, 2, 5, 6, 9, 10]
    assert CameraSelect(3, (1,), 0.5).output_width(12) == 2
    with pytest.raises(ValueError, match="use_tiles"):
        CameraSelect(3, (3,), 1.0)


def test_target_point_norm_maps_range_to_unit_and_clamps():
    norm = TargetPointNorm((-200.0, -50.0), (200.0, 50.0))
    points = torch.tensor([[-200.0, -50.0], [200.0, 50.0], [100.0, 25.0], [1000.0, -1000.0]])
    assert norm(points).tolist() == [[-1.0, -1.0], [1.0, 1.0], [0.5, 0.5], [1.0, -1.0]]


def test_target_point_norm_range_can_be_reset_and_lives_in_the_state_dict():
    model = TFv6(tfv6_config(**TINY))
    model.set_target_point_range((0.0, -10.0), (40.0, 10.0))
    assert model.target_point_range == ((0.0, -10.0), (40.0, 10.0))
    assert model.planner.status.tp_norm(torch.tensor([[30.0, 5.0]])).tolist() == [[0.5, 0.5]]
    state = model.state_dict()
    assert state["planner.status.tp_norm.low"].tolist() == [0.0, -10.0]
    fresh = TFv6(tfv6_config(**TINY))
    fresh.load_state_dict(state)
    assert fresh.target_point_range == ((0.0, -10.0), (40.0, 10.0))
    with pytest.raises(ValueError, match="must exceed"):
        model.set_target_point_range((0.0, 5.0), (40.0, 5.0))


def test_tfv5_context_holds_speed_and_command_tokens_only():
    """LEAD's TFv5: the current target point initialises the GRUs and is no decoder token."""
    config = tfv5_config(**TINY, decoder_dropout=0.0, fusion_dropout=0.0)
    model = TFv6(config).eval()
    assert model.reads_target_points and model.planner.status.target_point is None
    batch = random_batch(config, 2, "carla")
    tokens, pad = model.planner.status(batch)
    assert tokens.shape == (2, 2, config.token_dim) and not pad.any()  # speed, command
    memory = {}
    hook = model.planner.decoder.register_forward_hook(lambda module, args, out: memory.update(m=args[1]))
    out = model(batch, "carla", {"waypoints"})["waypoints"]
    hook.remove()
    hb, wb = config.bev.shape
    assert memory["m"].shape[1] == max(1, hb // 32) * max(1, wb // 32) + 2  # BEV tokens + speed + command
    batch["target_points"][:, 1] += 20.0  # the current target point still steers the plan, through the GRUs
    assert not torch.allclose(model(batch, "carla", {"waypoints"})["waypoints"], out)
    batch["target_points"][:, [0, 2]] += 20.0  # previous and next never reach TFv5
    moved = model(batch, "carla", {"waypoints"})["waypoints"]
    batch["target_points"][:, [0, 2]] -= 20.0
    torch.testing.assert_close(model(batch, "carla", {"waypoints"})["waypoints"], moved)
    with pytest.raises(ValueError, match="no target-point tokens"):
        TFv6(tfv5_config(**TINY, target_points=("current",)))


def test_target_point_range_from_info():
    info = {"statistics": {"target_points": {"low": [-5.0, -30.0], "high": [80.0, 30.0]}}}
    assert target_point_range(info) == ((-5.0, -30.0), (80.0, 30.0))
    with pytest.raises(KeyError, match="target_points"):
        target_point_range({"statistics": {}})


def test_masked_target_points_do_not_change_the_plan():
    config = tfv6_config(**TINY, decoder_dropout=0.0, fusion_dropout=0.0)
    model = TFv6(config).eval()
    batch = random_batch(config, 2, "carla")
    batch["target_points_valid"][:, 2] = False
    out = model(batch, "carla", {"waypoints"})["waypoints"]
    batch["target_points"][:, 2] += 37.0  # an absent next target point may hold anything
    torch.testing.assert_close(model(batch, "carla", {"waypoints"})["waypoints"], out)
    batch["target_points"][:, 1] += 37.0  # the present current target point matters
    assert not torch.allclose(model(batch, "carla", {"waypoints"})["waypoints"], out)


@settings(max_examples=50, deadline=None)
@given(st.floats(-5.0, 30.0))
def test_two_hot_decodes_to_the_clamped_value(speed):
    classes = torch.tensor(tfv6_config().target_speed_classes)
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


def test_segmentation_loss_is_the_mean_over_labelled_pixels():
    logits = torch.zeros(1, 4, 2, 2, requires_grad=True)  # uniform: log 4 per labelled pixel
    labels = torch.tensor([[[0, -1], [3, -1]]])
    assert segmentation_loss(logits, labels).item() == pytest.approx(math.log(4))
    unlabelled = segmentation_loss(logits, torch.full((1, 2, 2), -1))
    assert unlabelled.item() == 0.0 and unlabelled.requires_grad


def test_sine_embedding_shapes_and_distinct_cells():
    emb = grid_embedding(3, 4, 16)
    assert emb.shape == (12, 16)
    assert torch.cdist(emb, emb).add(torch.eye(12) * 1e3).min() > 1e-3
    with pytest.raises(ValueError, match="divisible by 4"):
        sine_embedding(torch.zeros(2), 6)


def test_ego_mlp_outputs_every_grid():
    model = EgoStatusMLP(EgoMLPConfig(hidden=16))
    config = tfv6_config(**TINY)
    for source in SOURCES:
        out = model(random_batch(config, 3, source), source)
        assert out["waypoints"].shape == (3, config.trajectory_grids[source].num_points, 2)
        assert out["headings"].shape == (3, config.trajectory_grids[source].num_points)


def test_focal_loss_ignores_unlabelled_cells():
    logits = torch.randn(1, 1, 4, 4, generator=torch.Generator().manual_seed(0))
    target = torch.zeros(1, 1, 4, 4)
    target[0, 0, 0, 0] = 1.0
    target[0, 0, 1, 1] = 0.5
    partial = target.clone()
    partial[..., 2:, :] = -1.0  # rows without a label (filled by collate for a sample without boxes)
    labelled_rows_only = focal_heatmap_loss(logits[..., :2, :], target[..., :2, :])
    assert torch.isclose(focal_heatmap_loss(logits, partial), labelled_rows_only)
    assert focal_heatmap_loss(logits, partial) < focal_heatmap_loss(logits, target)  # the ignored cells counted before


@pytest.mark.parametrize("variant", ["ltfv6", "tfv5"])
def test_output_scales_multiply_their_outputs_and_nothing_else(variant):
    """The same weights with ``trajectory_scale`` s and ``heading_scale`` h give s times the route and waypoints, h
    times the headings (TFv5 has none), and the same everything else."""
    plain = TFv6(VARIANTS[variant](**TINY, decoder_dropout=0.0, fusion_dropout=0.0)).eval()
    options = {"decoder_dropout": 0.0, "fusion_dropout": 0.0, "trajectory_scale": 7.5, "heading_scale": 0.25}
    scaled = TFv6(VARIANTS[variant](**TINY, **options)).eval()
    scaled.load_state_dict(plain.state_dict())
    batch = random_batch(plain.config, 2, "navsim")
    with torch.no_grad():
        before, after = plain(batch, "navsim"), scaled(batch, "navsim")
    factors = {"route": 7.5, "waypoints": 7.5, "headings": 0.25}
    assert ("headings" in before) == (variant != "tfv5")
    for key in before:
        torch.testing.assert_close(after[key], factors.get(key, 1.0) * before[key])
