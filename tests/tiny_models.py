"""Model sizes shared by the model and training tests: LEAD's field names at toy size (timm's ``test_*`` encoders),
small enough for two shared CPU cores; the switches that make a variant (``lead_driver.tfv6``, ...) are the
builder's."""

from dataclasses import replace
from typing import Any

from lead_s2r.models.config import default_grids
from lead_s2r.models.input_spec import InputSpec

#: Widths and depths of a tiny network of the one TransFuser family (as ``recipes/smoke/twin_lead.yaml``).
TINY = dict(
    use_mixed_precision_training=False,
    image_architecture="test_convnext",
    lidar_architecture="test_resnet",
    camera_tile_size=[32, 32],
    n_layer=1,
    pixels_per_meter=2.0,
    bev_features_chanels=16,
    bb_input_channel=16,
    radar_token_dim=32,
    radar_hidden_dim_tokenizer=64,
    radar_tf_dim_ff=64,
    radar_hidden_dim_decoder=64,
    radar_num_layers=1,
    transfuser_num_bev_cross_attention_layers=1,
    transfuser_num_bev_cross_attention_heads=4,
    transfuser_token_dim=32,
    deconv_channel_num_0=16,
    deconv_channel_num_1=16,
    deconv_channel_num_2=8,
)

#: A tiny LTFv6 for NAVSIM (``ltfv6_navsim``) on one camera tile the size of tests/toy_adapter.py's front image.
TOY_LTFV6 = {**TINY, "used_cameras": [False, True, False, False], "camera_tile_size": [64, 32]}
#: LTFv6's switches, for a recipe that names ``LeadDriver`` with a config (``ltfv6_navsim`` is the builder).
LTFV6_SWITCHES = {"use_navsim_data": True, "use_carla_data": False, "LTF": True, "use_planning_decoder": True}


def sensor_spec(**overrides: Any) -> InputSpec:
    """What the transform tests feed: every sensor and label a CARLA sample has, in the stored classes (not LEAD's
    tables), on the paper's 1152x384 mosaic and LEAD's CARLA BEV; for the data side alone, no network behind it."""
    spec = InputSpec(
        trajectory_grids=default_grids(),
        lidar_raster=True,
        radar=True,
        radar_sources=("carla",),
        bev_semantic_classes={"carla": 9, "navsim": 7},
        semantic_classes={"carla": 10},
        depth_sources=("carla",),
    )
    return replace(spec, **{k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()})
