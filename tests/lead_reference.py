"""Seeded weights and inputs for the LEAD reference cases in tests/data/lead_tfv6/reference_*.pt.

The stored outputs were computed by LEAD's own ``TFv6`` (kesai-labs/lead @ 4489176, ``lead/tfv6``, CPU, float32, one
thread) from exactly these weights and inputs, so the weights themselves need not be stored. See
tests/data/lead_tfv6/README.md.
"""

import torch

#: Small CARLA networks (timm test encoders, 2 px/m BEV; perspective and BEV-semantic heads off to keep the stored
#: outputs small) so LEAD's TFv6 with LiDAR and radar, and TFv5, run in seconds.
TINY_CARLA = {
    "use_mixed_precision_training": False,
    "image_architecture": "test_convnext",
    "lidar_architecture": "test_resnet",
    "n_layer": 1,
    "pixels_per_meter": 2.0,
    "bev_features_chanels": 16,
    "bb_input_channel": 16,
    "radar_token_dim": 32,
    "radar_hidden_dim_tokenizer": 64,
    "radar_tf_dim_ff": 64,
    "radar_hidden_dim_decoder": 64,
    "radar_num_layers": 2,
    "transfuser_num_bev_cross_attention_layers": 2,
    "transfuser_num_bev_cross_attention_heads": 4,
    "transfuser_token_dim": 32,
    "deconv_channel_num_0": 16,
    "deconv_channel_num_1": 16,
    "deconv_channel_num_2": 8,
    "use_semantic": False,
    "use_depth": False,
    "use_bev_semantic": False,
    "use_planning_decoder": True,
}
CASES = {
    "tfv6_radar": TINY_CARLA,
    "tfv5_gru": {**TINY_CARLA, "use_tfv5_planning_decoder": True},
}


def seeded_state(state: dict[str, torch.Tensor], seed: int = 0) -> dict[str, torch.Tensor]:
    """Random values for every floating entry, drawn in sorted key order (BatchNorm variances kept positive)."""
    generator = torch.Generator().manual_seed(seed)
    out = {}
    for key in sorted(state):
        value = state[key]
        if value.is_floating_point():
            draw = torch.randn(value.shape, generator=generator) * 0.1
            value = draw.abs() + 0.5 if key.endswith("running_var") else draw
        out[key] = value
    return out


def seeded_inputs(config: dict, seed: int = 1) -> dict[str, torch.Tensor]:
    """One CARLA sample in LEAD's input contract: 384 x 1152 RGB, LiDAR raster, 300 radar rows, route target points."""
    g = torch.Generator().manual_seed(seed)
    bev_h, bev_w = int(80 * config["pixels_per_meter"]), int(96 * config["pixels_per_meter"])
    xy = torch.stack([torch.rand(1, 300, generator=g) * 96 - 32, torch.rand(1, 300, generator=g) * 80 - 40], -1)
    sensor = torch.arange(300).div(75, rounding_mode="floor").float()[None, :, None]
    radar = torch.cat([xy, torch.randn(1, 300, 1, generator=g), torch.randn(1, 300, 1, generator=g) * 5, sensor], -1)
    return {
        "rgb": torch.randint(0, 256, (1, 3, 384, 1152), dtype=torch.uint8, generator=g),
        "rasterized_lidar": torch.rand(1, 1, bev_h, bev_w, generator=g),
        "radar": radar,
        "speed": torch.tensor([7.5]),
        "command": torch.eye(6)[[3]],
        "target_point": torch.tensor([[12.0, -3.0]]),
        "target_point_previous": torch.tensor([[-2.0, 0.5]]),
        "target_point_next": torch.tensor([[40.0, 9.0]]),
    }
