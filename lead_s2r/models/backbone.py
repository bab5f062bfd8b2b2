"""TransFuser backbone: timm image and BEV encoders run stage by stage with transformer fusion after each stage."""

from collections import OrderedDict
from dataclasses import dataclass

import timm
import torch
import torch.nn.functional as F
from timm.models import parse_model_name
from torch import Tensor, nn

from lead_s2r.models.config import TFv6Config
from lead_s2r.models.fusion import FusionBlock
from lead_s2r.models.inputs import lidar_input

NUM_STAGES = 4


class StagedEncoder(nn.Module):
    """A timm ``features_only`` encoder split into its last four feature stages, so fusion can run in between."""

    def __init__(self, architecture: str, pretrained: bool, in_chans: int) -> None:
        super().__init__()
        hub = isinstance(architecture, str) and parse_model_name(architecture)[0] is not None  # hf-hub:org/name
        if not isinstance(architecture, str) or not (hub or timm.is_model(architecture)):
            raise ValueError(f"{architecture!r} is no timm architecture; see timm.list_models() for the names")
        try:
            net = timm.create_model(architecture, features_only=True, pretrained=pretrained, in_chans=in_chans)
        except Exception as err:  # timm raises several types for unknown names and unreachable weights
            hint = " (set pretrained: false or put the weights in the Hugging Face cache)" if pretrained else ""
            raise RuntimeError(f"cannot build timm encoder {architecture!r}{hint}: {err}") from err
        if not isinstance(net, nn.ModuleDict) or not hasattr(net, "return_layers"):
            raise ValueError(
                f"timm encoder {architecture!r} ({type(net).__name__}) cannot run stage by stage; use an "
                "architecture whose features_only model is a FeatureListNet (resnet*, regnet*, convnext*, ...)"
            )
        ends = list(net.return_layers)[-NUM_STAGES:]
        stages, current = [], OrderedDict()
        for name, module in net.items():
            current[name] = module
            if name in ends:
                stages.append(nn.Sequential(current))
                current = OrderedDict()
            if len(stages) == NUM_STAGES:
                break
        self.stages = nn.ModuleList(stages)
        self.channels: list[int] = net.feature_info.channels()[-NUM_STAGES:]
        cfg = net.pretrained_cfg or {}
        self.mean = tuple(cfg.get("mean", (0.485, 0.456, 0.406)))
        self.std = tuple(cfg.get("std", (0.229, 0.224, 0.225)))


class CameraSelect(nn.Module):
    """Camera ablations on a horizontally stitched mosaic: keep some tiles, crop each to a central FOV share."""

    def __init__(self, tiles: int, use: tuple[int, ...] | None, fov_fraction: float) -> None:
        super().__init__()
        if not 0.0 < fov_fraction <= 1.0:
            raise ValueError(f"fov_fraction must be in (0, 1], got {fov_fraction}")
        if use is not None and any(not 0 <= t < tiles for t in use):
            raise ValueError(f"use_tiles {use} must index the {tiles} camera tiles")
        self.tiles, self.use, self.fov_fraction = tiles, use, fov_fraction

    @property
    def active(self) -> bool:
        return self.use is not None or self.fov_fraction < 1.0

    def forward(self, image: Tensor) -> Tensor:
        """Apply to any (..., H, W) image-aligned tensor: RGB, and depth/semantic labels alike."""
        if not self.active:
            return image
        width = image.shape[-1] // self.tiles
        keep = round(width * self.fov_fraction)
        start = (width - keep) // 2
        use = self.use if self.use is not None else range(self.tiles)
        return torch.cat([image[..., t * width + start : t * width + start + keep] for t in use], dim=-1)

    def output_width(self, width: int) -> int:
        if not self.active:
            return width
        use = self.use if self.use is not None else range(self.tiles)
        return len(use) * round(width // self.tiles * self.fov_fraction)


@dataclass
class BackboneFeatures:
    image: Tensor  # (B, C_img, H/32, W/32) fused image features
    bev: Tensor  # (B, C_bev, Hb/32, Wb/32) fused BEV features, source of the planner's BEV tokens
    bev_grid: Tensor  # (B, bev_feature_channels, Hb/4, Wb/4) feature pyramid output for dense BEV heads


class TransfuserBackbone(nn.Module):
    """Image + BEV encoders with 4-stage fusion and a top-down BEV feature pyramid.

    The BEV branch reads the LiDAR raster (TFv6), a fixed 2-channel coordinate grid (LTFv6) or a learned latent.
    """

    def __init__(self, config: TFv6Config) -> None:
        super().__init__()
        self.config = config
        self.cameras = CameraSelect(config.camera_tiles, config.use_tiles, config.fov_fraction)
        bev_channels = {"raster": config.lidar_channels, "coordinates": 2, "latent": config.lidar_channels}
        self.image_encoder = StagedEncoder(config.image_architecture, config.pretrained, 3)
        self.bev_encoder = StagedEncoder(config.bev_architecture, False, bev_channels[config.bev_input])
        self.register_buffer("mean", torch.tensor(self.image_encoder.mean).view(1, 3, 1, 1) * 255, persistent=False)
        self.register_buffer("std", torch.tensor(self.image_encoder.std).view(1, 3, 1, 1) * 255, persistent=False)
        hb, wb = config.bev.shape
        if config.bev_input == "coordinates":
            rows = torch.linspace(0, 1, hb).view(hb, 1).expand(hb, wb)
            cols = torch.linspace(0, 1, wb).view(1, wb).expand(hb, wb)
            self.register_buffer("bev_constant", torch.stack([rows, cols])[None], persistent=False)
        elif config.bev_input == "latent":
            self.bev_latent = nn.Parameter(torch.randn(1, config.lidar_channels, hb, wb))
        h, w = config.image_size
        image_anchor = (max(1, h // 32), max(1, self.cameras.output_width(w) // 32))
        bev_anchor = (max(1, hb // 32), max(1, wb // 32))
        self.fusion = nn.ModuleList(
            FusionBlock(
                ci, cb, image_anchor, bev_anchor, config.fusion_layers, config.fusion_heads, config.fusion_dropout
            )
            for ci, cb in zip(self.image_encoder.channels, self.bev_encoder.channels, strict=True)
        )
        c = config.bev_feature_channels
        self.lateral = nn.ModuleList(nn.Conv2d(cb, c, 1) for cb in self.bev_encoder.channels)
        self.smooth = nn.Sequential(nn.Conv2d(c, c, 3, padding=1), nn.ReLU(inplace=True), nn.Conv2d(c, c, 3, padding=1))

    @property
    def image_channels(self) -> int:
        return self.image_encoder.channels[-1]

    @property
    def bev_channels(self) -> int:
        return self.bev_encoder.channels[-1]

    def bev_input(self, batch_size: int, lidar_bev: Tensor | None, like: Tensor) -> Tensor:
        if self.config.bev_input == "raster":
            if lidar_bev is None:
                raise KeyError("TFv6 with bev_input='raster' needs 'lidar_bev' (B, C, Hb, Wb) in the batch")
            return lidar_input(lidar_bev, like.dtype)
        constant = self.bev_constant if self.config.bev_input == "coordinates" else self.bev_latent
        return constant.to(like.dtype).expand(batch_size, -1, -1, -1)

    def forward(self, rgb: Tensor, lidar_bev: Tensor | None = None) -> BackboneFeatures:
        image = (self.cameras(rgb).float() - self.mean) / self.std
        bev = self.bev_input(rgb.shape[0], lidar_bev, image)
        bev_maps = []
        for img_stage, bev_stage, fuse in zip(
            self.image_encoder.stages, self.bev_encoder.stages, self.fusion, strict=True
        ):
            image, bev = fuse(img_stage(image), bev_stage(bev))
            bev_maps.append(bev)
        grid = self.lateral[-1](bev_maps[-1])
        for lateral, bev_map in zip(self.lateral[-2::-1], bev_maps[-2::-1], strict=True):
            grid = lateral(bev_map) + F.interpolate(grid, size=bev_map.shape[-2:], mode="bilinear", align_corners=False)
        hb, wb = self.config.bev.shape
        grid = F.interpolate(grid, size=(hb // 4, wb // 4), mode="bilinear", align_corners=False)
        return BackboneFeatures(image=image, bev=bev, bev_grid=self.smooth(grid))
