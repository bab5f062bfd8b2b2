"""LEAD's loss on the seeded CARLA networks of ``tests/lead_reference.py`` (TFv6 with LiDAR, radar, perspective and
BEV heads; the same on one camera, where LEAD's BEV frustum mask bites; TFv5 with a braking sample): every term,
the total and each parameter's gradient norm, against the values LEAD's own ``TFv6.compute_loss`` and Trainer
weighting gave for the same weights, inputs and :func:`seeded_targets` (``tests/data/lead_tfv6/loss_reference.json``,
made as its ``source`` says)."""

import json
from pathlib import Path

import pytest
import torch
from lead_reference import TINY_CARLA, seeded_inputs, seeded_state
from torch import Tensor

from lead_s2r.models import lead
from lead_s2r.models.lead_config import LeadConfig

pytestmark = pytest.mark.usefixtures("one_thread")

REFERENCE = json.loads((Path(__file__).parent / "data" / "lead_tfv6" / "loss_reference.json").read_text())
WITH_PERCEPTION = dict(TINY_CARLA, use_semantic=True, use_depth=True, use_bev_semantic=True)
#: name -> (config overrides, whether the second sample brakes)
CASES = {
    "tfv6_radar_perception": (WITH_PERCEPTION, False),
    "tfv6_radar_one_camera": (dict(WITH_PERCEPTION, used_cameras=[False, True, False]), False),
    "tfv5_gru_brake": (dict(TINY_CARLA, use_tfv5_planning_decoder=True), True),
}


def seeded_targets(config: LeadConfig, brake: bool) -> dict[str, Tensor]:
    """Two CARLA samples of LEAD's labels: random maps, four CenterNet peaks (two classes, two in one sample), 3 and 2
    radar detections in the query slots, target speeds 6.7 and 25 m/s (the second braking when ``brake``)."""
    g = torch.Generator().manual_seed(3)
    b, h, w = 2, config.lidar_height_pixel, config.lidar_width_pixel
    image = (b, config.final_image_height, config.final_image_width)
    grid = (h // config.bev_down_sample_factor, w // config.bev_down_sample_factor)
    heatmap = torch.rand(b, config.num_bb_classes, *grid, generator=g) ** 4
    weight = torch.zeros(b, 2, *grid)
    for sample, cls, row, col in ((0, 1, 3, 5), (0, 4, 7, 2), (1, 0, 2, 9), (1, 0, 2, 10)):
        heatmap[sample, cls, row, col] = 1.0
        weight[sample, :, row, col] = 1.0
    detections = torch.zeros(b, config.num_radar_queries, 4)
    detections[0, :3] = torch.tensor([[10.0, 3.0, 5.0, 1.0], [30.0, -20.0, 12.0, 1.0], [-5.0, 8.0, 0.5, 1.0]])
    detections[1, :2] = torch.tensor([[50.0, 30.0, 20.0, 1.0], [2.0, -2.0, 1.0, 1.0]])
    return {
        "source_dataset": torch.ones(b, dtype=torch.int64),
        "semantic": torch.randint(0, config.num_semantic_classes, image, generator=g).to(torch.uint8),
        "depth": torch.rand(image, generator=g) * 49 + 1,
        "bev_semantic": torch.randint(0, config.num_bev_semantic_classes, (b, h, w), generator=g).to(torch.uint8),
        "center_net_heatmap": heatmap,
        "center_net_wh": torch.rand(b, 2, *grid, generator=g) * 3 * weight,
        "center_net_offset": torch.rand(b, 2, *grid, generator=g) * weight,
        "center_net_yaw_class": torch.randint(0, config.num_dir_bins, (b, *grid), generator=g).int(),
        "center_net_yaw_res": (torch.rand(b, 1, *grid, generator=g) - 0.5) * 0.5,
        "center_net_velocity": torch.rand(b, 1, *grid, generator=g) * 10,
        "center_net_pixel_weight": weight,
        "center_net_avg_factor": torch.tensor([2, 2]),
        "radar_detections": detections,
        "future_waypoints": torch.randn(b, 8, 2, generator=g) * 5,
        "future_yaws": torch.randn(b, 8, generator=g) * 0.2,
        "route": torch.randn(b, 10, 2, generator=g) * 5,
        "target_speed": torch.tensor([6.7, 25.0]),
        "brake": torch.tensor([False, brake]),
    }


def batch_of_two(overrides: dict, config: LeadConfig) -> dict[str, Tensor]:
    """The seeded sample and its colour negative, the image cut to the configured cameras' width."""
    inputs = {key: torch.cat([value, value]) for key, value in seeded_inputs(overrides).items()}
    inputs["rgb"][1] = 255 - inputs["rgb"][1]
    inputs["rgb"] = inputs["rgb"][..., : config.final_image_width]
    return inputs


def case_run(overrides: dict, brake: bool) -> tuple[torch.nn.Module, dict[str, Tensor]]:
    model = lead.model_from_config(dict(overrides))
    model.load_state_dict(seeded_state(model.state_dict()))
    model.eval()
    losses = lead.loss(model, batch_of_two(overrides, model.config), seeded_targets(model.config, brake))
    return model, losses


@pytest.mark.parametrize("name", sorted(CASES))
def test_terms_total_and_gradients_are_leads(name: str) -> None:
    want = REFERENCE["cases"][name]
    model, losses = case_run(*CASES[name])
    assert list(losses) == [*want["terms"], "total"]
    for key, value in want["terms"].items():
        assert losses[key].item() == pytest.approx(value, rel=1e-5, abs=1e-5), key
    assert losses["total"].item() == pytest.approx(want["total"], rel=1e-5)
    losses["total"].backward()
    largest = max(want["grad_norms"].values())
    for param_name, p in model.named_parameters():
        norm = 0.0 if p.grad is None else p.grad.norm().item()
        assert norm == pytest.approx(want["grad_norms"][param_name], rel=1e-4, abs=1e-5 * largest), param_name
