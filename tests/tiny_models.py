"""Model sizes shared by the model and training tests."""

from lead_s2r.models.config import BEVGrid

#: A model small enough for two shared CPU cores; timm's ``test_*`` encoders.
TINY = dict(
    image_architecture="test_convnext",
    bev_architecture="test_convnext",
    image_size=(32, 64),
    bev=BEVGrid(-8.0, 8.0, -8.0, 8.0, 2.0),
    token_dim=32,
    decoder_layers=1,
    decoder_heads=4,
    decoder_ffn=64,
    radar_queries=4,
    radar_layers=1,
    radar_ffn=64,
    bev_feature_channels=16,
    fusion_layers=1,
)
