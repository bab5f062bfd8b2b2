"""LEAD's loss terms one by one (``lead_s2r.models.lead_loss``), with hand-worked numbers: the terms the NAVSIM golden
case does not reach (radar Hungarian matching, CARLA CenterNet with several classes and velocity, perspective
semantics and depth, TFv5's planner terms, the two-hot target speed) and the quirks LEAD's code has."""

import math

import pytest
import torch
import torch.nn.functional as F

from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_loss import (
    bev_semantic_loss,
    center_net_losses,
    depth_loss,
    loss_weights,
    planning_losses,
    radar_loss,
    semantic_loss,
    two_hot,
    visible_bev_pixels,
)

SCALE = (96.0, 80.0, 25.0)  # CARLA's x extent, y extent (m) and max speed (m/s)
LN2 = math.log(2)


def radar_case() -> tuple[torch.Tensor, torch.Tensor]:
    """One sample, two queries, two label slots: slot 0 a real detection, slot 1 padding. Query 1 sits 9.6 m in x
    from the detection (0.1 of the x extent), query 0 far away; logits 3 (query 1) and -2 (query 0)."""
    detections = torch.tensor([[[10.0, 4.0, 5.0, 1.0], [0.0, 0.0, 0.0, 0.0]]])
    pred = torch.tensor([[[-30.0, 30.0, 20.0, -2.0], [19.6, 4.0, 5.0, 3.0]]], requires_grad=True)
    return pred, detections


def test_radar_matches_by_hungarian_cost_and_mixes_l1_and_bce() -> None:
    pred, detections = radar_case()
    # query 1 <-> the detection (L1 0.1), query 0 <-> padding (L1 masked); BCE of both matched pairs averaged
    want = 5 * 0.1 + (F.softplus(torch.tensor(-3.0)) + F.softplus(torch.tensor(-2.0))).item() / 2
    assert radar_loss(pred, detections, SCALE).item() == pytest.approx(want, rel=1e-6)


def test_radar_is_invariant_to_query_order_and_trains_only_matched_states() -> None:
    pred, detections = radar_case()
    value = radar_loss(pred, detections, SCALE)
    value.backward()
    assert torch.all(pred.grad[0, 0, :3] == 0)  # matched to padding: its state is not trained
    assert pred.grad[0, 1, 0].item() == pytest.approx(5 / 96 / 1, rel=1e-6)  # d(5 * |dx| / 96) / dx
    swapped = pred.detach().flip(1)
    assert radar_loss(swapped, detections, SCALE).item() == pytest.approx(value.item(), rel=1e-7)


def test_radar_normalises_l1_per_sample_by_its_valid_slots_then_averages_samples() -> None:
    detections = torch.tensor([[[10.0, 0.0, 0.0, 1.0], [20.0, 0.0, 0.0, 1.0]], [[10.0, 0.0, 0.0, 1.0], [0.0] * 4]])
    exact = detections.clone()
    exact[..., 3] = 50.0  # confident logits: BCE ~ 0 on valid slots
    exact[1, 1, 3] = -50.0
    off = exact.clone()
    off[0, :, 0] += 9.6  # both detections of sample 0 off by 0.1 of the x extent
    off[1, 0, 0] += 19.2  # sample 1's only detection off by 0.2
    value = radar_loss(off, detections, SCALE).item()
    assert value == pytest.approx((5 * 0.1 + 5 * 0.2) / 2, rel=1e-5)


def centernet_case(velocity_target: float = 7.0) -> tuple[dict, dict]:
    """Two classes on a 4 x 5 grid, probabilities 0.5 everywhere, zero regressions. Sample 0: one box of class 1 at
    (2, 3); sample 1: two boxes of class 0 (avg factor 2)."""
    b, c, h, w = 2, 2, 4, 5
    heatmap = torch.zeros(b, c, h, w)
    weight = torch.zeros(b, 2, h, w)
    wh, offset = torch.zeros(b, 2, h, w), torch.zeros(b, 2, h, w)
    yaw_res, velocity = torch.zeros(b, 1, h, w), torch.zeros(b, 1, h, w)
    for sample, cls, row, col in ((0, 1, 2, 3), (1, 0, 0, 0), (1, 0, 3, 4)):
        heatmap[sample, cls, row, col] = 1.0
        weight[sample, :, row, col] = 1.0
        wh[sample, :, row, col] = torch.tensor([3.0, 1.0])
        offset[sample, :, row, col] = torch.tensor([0.25, 0.75])
        yaw_res[sample, 0, row, col] = 0.5
        velocity[sample, 0, row, col] = velocity_target
    pred = {
        "center_heatmap_pred": torch.full((b, c, h, w), 0.5),
        "wh_pred": torch.zeros(b, 2, h, w),
        "offset_pred": torch.zeros(b, 2, h, w),
        "yaw_class_pred": torch.zeros(b, 12, h, w),
        "yaw_res_pred": torch.zeros(b, 1, h, w),
        "velocity_pred": torch.zeros(b, 1, h, w),
    }
    target = {
        "center_net_heatmap": heatmap,
        "center_net_wh": wh,
        "center_net_offset": offset,
        "center_net_yaw_class": torch.zeros(b, h, w, dtype=torch.int32),
        "center_net_yaw_res": yaw_res,
        "center_net_velocity": velocity,
        "center_net_pixel_weight": weight,
        "center_net_avg_factor": torch.tensor([1, 2]),
    }
    return pred, target


def test_centernet_terms_are_normalised_per_sample() -> None:
    pred, target = centernet_case()
    got = center_net_losses(pred, target, torch.tensor([True, True]))
    eps = torch.finfo(torch.float32).eps
    cells = 2 * 4 * 5  # every cell is a positive or a negative at p = 0.5: -ln(0.5) * 0.5^2
    per_box = {"wh": (3 + 1) / 2, "offset": (0.25 + 0.75) / 2, "yaw_class": math.log(12), "yaw_res": 0.125}
    per_box["velocity"] = 7.0
    assert got["loss_center_net_heatmap"].item() == pytest.approx(
        (cells * LN2 / 4 / (1 + eps) + cells * LN2 / 4 / (2 + eps)) / 2, rel=1e-6
    )
    for term, value in per_box.items():  # sample 0: one box / 1, sample 1: two boxes / 2 -> the per-box value
        assert got[f"loss_center_net_{term}"].item() == pytest.approx(value, rel=1e-6), term


def test_centernet_masks_other_sources_and_can_leave_velocity_out() -> None:
    pred, target = centernet_case()
    target["center_net_wh"][1] = 100.0  # sample 1 is another source's: its labels must not count
    got = center_net_losses(pred, target, torch.tensor([True, False]), velocity=False)
    assert got["loss_center_net_wh"].item() == pytest.approx(2.0, rel=1e-6)
    assert torch.equal(got["loss_center_net_velocity"], torch.zeros(1))


def test_depth_label_is_truncated_to_whole_metres_and_masked_by_source() -> None:
    label = torch.full((2, 3, 4), 2.7)
    depth = torch.full((2, 3, 4), 2.5)
    depth[1] = 100.0  # another source's sample
    assert depth_loss(depth, label, torch.tensor([True, False])).item() == pytest.approx(0.5)


def test_semantic_loss_is_the_per_sample_pixel_mean() -> None:
    logits = torch.zeros(2, 5, 3, 4)
    logits[0, 2] = 50.0  # sample 0 predicts class 2 everywhere, the label
    label = torch.full((2, 3, 4), 2, dtype=torch.uint8)
    assert semantic_loss(logits, label, torch.tensor([True, True])).item() == pytest.approx(math.log(5) / 2)


def test_bev_loss_counts_invisible_pixels_in_the_mean() -> None:
    """One front camera: pixels behind are ignored but still divide, so uniform logits give ln K x visible share."""
    config = LeadConfig(used_cameras=[False, True, False], pixels_per_meter=1.0)
    visible = visible_bev_pixels(config)
    h, w = config.lidar_height_pixel, config.lidar_width_pixel
    assert visible.shape == (h, w) and visible[h // 2, -1] == 1 and visible[h // 2, 0] == 0
    share = visible.mean().item()
    assert 0.2 < share < 0.5
    logits = torch.zeros(1, 7, h, w)
    label = torch.randint(0, 7, (1, h, w))
    got = bev_semantic_loss(logits, label, visible, torch.tensor([True])).item()
    assert got == pytest.approx(math.log(7) * share, rel=1e-6)
    assert torch.equal(visible_bev_pixels(LeadConfig()), torch.ones(320, 384))  # three cameras: all visible


def test_two_hot_splits_between_neighbouring_classes_with_brake_and_top_overrides() -> None:
    speeds = torch.tensor([6.0, 25.0, 9.0, 0.0, 20.0])
    brake = torch.tensor([False, False, True, False, False])
    encoded = two_hot(speeds, brake)
    assert encoded[0].tolist() == pytest.approx([0, 0.5, 0.5, 0, 0, 0, 0, 0])
    assert encoded[1].tolist() == [0, 0, 0, 0, 0, 0, 0, 1]
    assert encoded[2].tolist() == [1, 0, 0, 0, 0, 0, 0, 0]
    assert encoded[3].tolist() == [1, 0, 0, 0, 0, 0, 0, 0]
    assert encoded[4].tolist() == [0, 0, 0, 0, 0, 0, 0, 1]


def planning_case() -> tuple[dict, dict]:
    g = torch.Generator().manual_seed(0)
    outputs = {
        "pred_future_waypoints": torch.randn(2, 8, 2, generator=g),
        "pred_route": torch.randn(2, 10, 2, generator=g),
        "pred_target_speed_distribution": torch.randn(2, 8, generator=g),
    }
    targets = {
        "future_waypoints": torch.randn(2, 8, 2, generator=g),
        "route": torch.randn(2, 10, 2, generator=g),
        "target_speed": torch.tensor([6.0, 3.0]),
        "brake": torch.tensor([False, True]),
    }
    return outputs, targets


def test_tfv5_terms_are_plain_l1_and_two_hot_ce_without_the_route_end_term() -> None:
    outputs, targets = planning_case()
    config = LeadConfig(use_planning_decoder=True, use_tfv5_planning_decoder=True)
    got = planning_losses(config, outputs, targets)
    assert list(got) == ["loss_tf", "loss_tfpp_speed", "loss_tfpp"]
    route_l1 = (outputs["pred_route"] - targets["route"]).abs().mean()
    assert got["loss_tfpp"].item() == pytest.approx(route_l1.item(), rel=1e-6)
    tfv6 = planning_losses(LeadConfig(use_planning_decoder=True), outputs, targets)
    end = (outputs["pred_route"][:, -1] - targets["route"][:, -1]).abs().mean()
    assert tfv6["loss_spatial_route"].item() == pytest.approx((route_l1 + end).item(), rel=1e-6)
    assert got["loss_tf"].item() == pytest.approx(tfv6["loss_spatio_temporal_waypoints"].item(), rel=1e-6)
    speed = got["loss_tfpp_speed"].item()
    log_p = F.log_softmax(outputs["pred_target_speed_distribution"], -1)
    assert speed == pytest.approx(-(0.5 * log_p[0, 1] + 0.5 * log_p[0, 2] + log_p[1, 0]).item() / 2, rel=1e-6)


def test_tfv5_terms_weigh_as_the_tfv6_terms_they_stand_for() -> None:
    """LEAD's table has no TFv5 keys (its Trainer fails on them); each takes its TFv6 term's weight: CARLA TFv5 without
    semantics, depth and radar has ten unit weights."""
    config = LeadConfig(
        use_planning_decoder=True, use_tfv5_planning_decoder=True, use_semantic=False, radar_detection=False
    )
    weights = loss_weights(config)
    assert weights["loss_tf"] == weights["loss_tfpp_speed"] == weights["loss_tfpp"] == pytest.approx(0.1)
    assert sum(v for k, v in weights.items() if not k.startswith("loss_tf")) == pytest.approx(1.0)


def test_navsim_headings_go_into_the_waypoint_term() -> None:
    outputs, targets = planning_case()
    outputs["pred_headings"] = torch.zeros(2, 8)
    targets["future_yaws"] = torch.full((2, 8), 0.25)
    config = LeadConfig(use_planning_decoder=True, use_navsim_data=True, use_carla_data=False)
    got = planning_losses(config, outputs, targets)
    waypoints = (outputs["pred_future_waypoints"] - targets["future_waypoints"]).abs().mean().item()
    assert list(got) == ["loss_spatio_temporal_waypoints"]
    assert got["loss_spatio_temporal_waypoints"].item() == pytest.approx(waypoints + 0.25, rel=1e-6)
