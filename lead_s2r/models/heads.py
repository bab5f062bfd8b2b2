"""Dense auxiliary heads: BEV semantics and CenterNet boxes on the BEV grid, depth + semantics in perspective.

Each head instance serves one label space; the model keeps one per space (CARLA vs NAVSIM classes).
"""

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def conv_head(in_channels: int, out_channels: int, hidden: int = 64) -> nn.Sequential:
    """3x3 conv + ReLU + 1x1 conv, TransFuser's head shape."""
    return nn.Sequential(
        nn.Conv2d(in_channels, hidden, 3, padding=1), nn.ReLU(inplace=True), nn.Conv2d(hidden, out_channels, 1)
    )


class BEVSemanticHead(nn.Module):
    """Per-cell class logits on the BEV grid (stride 4); the loss resizes them to the label raster."""

    def __init__(self, in_channels: int, num_classes: int) -> None:
        super().__init__()
        self.head = conv_head(in_channels, num_classes)

    def forward(self, bev_grid: Tensor) -> dict[str, Tensor]:
        return {"bev_semantic": self.head(bev_grid)}


class CenterNetHead(nn.Module):
    """CenterNet boxes: class heatmap, centre offset, size, yaw (bin class + residual) and speed per cell."""

    def __init__(self, in_channels: int, num_classes: int, yaw_bins: int = 12) -> None:
        super().__init__()
        self.heatmap = conv_head(in_channels, num_classes)
        self.offset = conv_head(in_channels, 2)
        self.size = conv_head(in_channels, 2)
        self.yaw_class = conv_head(in_channels, yaw_bins)
        self.yaw_residual = conv_head(in_channels, 1)
        self.velocity = conv_head(in_channels, 1)
        # focal-loss prior: start with ~0.1 % foreground so early heatmap losses do not explode
        nn.init.constant_(self.heatmap[-1].bias, -6.9)

    def forward(self, bev_grid: Tensor) -> dict[str, Tensor]:
        return {
            "box_heatmap": self.heatmap(bev_grid),
            "box_offset": self.offset(bev_grid),
            "box_size": self.size(bev_grid),
            "box_yaw_class": self.yaw_class(bev_grid),
            "box_yaw_residual": self.yaw_residual(bev_grid),
            "box_velocity": self.velocity(bev_grid),
        }


class PerspectiveHead(nn.Module):
    """Depth (metres, bounded by ``max_depth``) and/or semantic logits at 1/8 image resolution from fused features.

    Two x2 upsampling stages from stride 32; the loss resizes to the label image.
    """

    def __init__(self, in_channels: int, semantic_classes: int | None, depth: bool, max_depth: float = 50.0) -> None:
        super().__init__()
        hidden = 64
        self.trunk = nn.Sequential(nn.Conv2d(in_channels, hidden, 3, padding=1), nn.ReLU(inplace=True))
        self.up = nn.ModuleList(
            nn.Sequential(nn.Conv2d(hidden, hidden, 3, padding=1), nn.ReLU(inplace=True)) for _ in range(2)
        )
        self.semantic = nn.Conv2d(hidden, semantic_classes, 1) if semantic_classes else None
        self.depth = nn.Conv2d(hidden, 1, 1) if depth else None
        self.max_depth = max_depth

    def forward(self, image_features: Tensor) -> dict[str, Tensor]:
        x = self.trunk(image_features)
        for block in self.up:
            x = block(F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False))
        out = {}
        if self.semantic is not None:
            out["semantic"] = self.semantic(x)
        if self.depth is not None:
            out["depth"] = torch.sigmoid(self.depth(x)).squeeze(1) * self.max_depth
        return out
