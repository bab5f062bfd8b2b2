"""Seeded weights and inputs for the cases computed with LEAD's own code in tests/data/lead_tfv6/ (reference_*.pt,
export_*.pt, ensemble_*.pt).

The stored values were computed by LEAD's own ``TFv6`` (kesai-labs/lead @ 4489176, ``lead/tfv6``, CPU, float32, one
thread) from exactly these weights and inputs, so the weights themselves need not be stored. See
tests/data/lead_tfv6/README.md.
"""

import torch

from lead_s2r.models.lead_config import LeadConfig

#: Toy widths and depths (timm test encoders, 2 px/m BEV, token dim 32) so LEAD's networks run in seconds on a CPU.
TINY_SIZE = {
    "use_mixed_precision_training": False,
    "image_architecture": "test_convnext",
    "lidar_architecture": "test_resnet",
    "n_layer": 1,
    "pixels_per_meter": 2.0,
    "bev_features_chanels": 16,
    "bb_input_channel": 16,
    "transfuser_token_dim": 32,
    "transfuser_num_bev_cross_attention_layers": 2,
    "transfuser_num_bev_cross_attention_heads": 4,
}
#: Small CARLA networks (LEAD's TFv6 with LiDAR and radar; TFv5), the perspective and BEV-semantic heads off (other
#: tests build on it).
TINY_CARLA = {
    **TINY_SIZE,
    "radar_token_dim": 32,
    "radar_hidden_dim_tokenizer": 64,
    "radar_tf_dim_ff": 64,
    "radar_hidden_dim_decoder": 64,
    "radar_num_layers": 2,
    "deconv_channel_num_0": 16,
    "deconv_channel_num_1": 16,
    "deconv_channel_num_2": 8,
    "use_semantic": False,
    "use_depth": False,
    "use_bev_semantic": False,
    "use_planning_decoder": True,
}
#: The same with every head LEAD has on: perspective semantics and depth, BEV semantics, CenterNet boxes, radar
#: detection and the planner. The front camera alone (a 384 x 384 input) and few classes keep the stored image-space
#: maps small; LEAD fixes the camera tile's size.
ALL_HEADS = {
    **TINY_CARLA,
    "used_cameras": [False, True, False],
    "num_semantic_classes": 2,
    "num_bev_semantic_classes": 3,
    "use_semantic": True,
    "use_depth": True,
    "use_bev_semantic": True,
}
#: The small NAVSIM LTFv6 of recipes/smoke/navsim_lead_ltfv6.yaml (the smoke run export-lead is shown on).
TINY_NAVSIM = {
    **TINY_SIZE,
    "use_navsim_data": True,
    "use_carla_data": False,
    "LTF": True,
    "use_planning_decoder": True,
    "used_cameras": [False, True, False, False],
}
#: Forward parity with every head: TFv6 with LiDAR and radar; TFv5 (only its planner differs, so its perspective
#: heads, pinned by the first case, stay off to keep the stored file small).
CASES = {
    "tfv6_radar": ALL_HEADS,
    "tfv5_gru": {**ALL_HEADS, "use_tfv5_planning_decoder": True, "use_semantic": False, "use_depth": False},
}
#: Configurations export-lead writes and LEAD's own loader read back strictly (export_<name>.pt): the smoke run's
#: NAVSIM LTFv6, the CARLA cases above, and a sim-to-real network (NAVSIM target with LEAD's CARLA heads).
EXPORTS = {
    "navsim_smoke": TINY_NAVSIM,
    "tfv6_radar": ALL_HEADS,
    "tfv5_gru": CASES["tfv5_gru"],
    "sim2real": {**ALL_HEADS, **TINY_NAVSIM, "use_carla_data": True},
}
#: Ensembles merged by LEAD's ``OpenLoopInference.ensemble`` (ensemble_<name>.pt): CARLA leaderboard mode, NAVSIM.
ENSEMBLES = {"carla": ALL_HEADS, "navsim": {**TINY_NAVSIM, "use_bev_semantic": True}}


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


def seeded_inputs(overrides: dict, seed: int = 1) -> dict[str, torch.Tensor]:
    """One sample in LEAD's input contract for the network ``overrides`` describes: RGB of its image size, its LiDAR
    raster unless LTF, CARLA's 300 radar rows and route target points, NAVSIM's acceleration, the command one-hot."""
    config = LeadConfig.from_json(overrides)
    g = torch.Generator().manual_seed(seed)
    height, width = config.final_image_height, config.final_image_width
    inputs = {
        "rgb": torch.randint(0, 256, (1, 3, height, width), dtype=torch.uint8, generator=g),
        "speed": torch.tensor([7.5]),
        "acceleration": torch.tensor([1.25]),
        "command": torch.eye(config.discrete_command_dim)[[min(3, config.discrete_command_dim - 1)]],
        "target_point": torch.tensor([[12.0, -3.0]]),
        "target_point_previous": torch.tensor([[-2.0, 0.5]]),
        "target_point_next": torch.tensor([[40.0, 9.0]]),
    }
    if not config.LTF:
        shape = (1, 1, config.lidar_height_pixel, config.lidar_width_pixel)
        inputs["rasterized_lidar"] = torch.rand(shape, generator=g)
    x = torch.rand(1, 300, generator=g) * (config.max_x_meter - config.min_x_meter) + config.min_x_meter
    y = torch.rand(1, 300, generator=g) * (config.max_y_meter - config.min_y_meter) + config.min_y_meter
    sensor = torch.arange(300).div(75, rounding_mode="floor").float()[None, :, None]
    z, velocity = torch.randn(1, 300, 1, generator=g), torch.randn(1, 300, 1, generator=g) * 5
    inputs["radar"] = torch.cat([torch.stack([x, y], -1), z, velocity, sensor], -1)
    return inputs


def thinned(outputs: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Maps (both last sides at least 32) at every 8th row and column, as export_*.pt and ensemble_*.pt store them:
    the values are pinned at those cells and the files stay small."""
    return {k: v[..., ::8, ::8] if v.dim() >= 3 and min(v.shape[-2:]) >= 32 else v for k, v in outputs.items()}
