"""Transformer fusion between the image and BEV feature maps of one encoder stage (TransFuser's GPT block)."""

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class FusionBlock(nn.Module):
    """Pool both maps to fixed anchors, run self-attention over the joint tokens, add the result back residually.

    The BEV map is projected to the image channel count and back when the two encoders differ. Anchors are fixed,
    so one set of learned positional embeddings serves every input size (CARLA and NAVSIM mosaics alike).
    """

    def __init__(
        self,
        image_channels: int,
        bev_channels: int,
        image_anchor: tuple[int, int],
        bev_anchor: tuple[int, int],
        layers: int = 2,
        heads: int = 4,
        dropout: float = 0.1,
    ) -> None:
        super().__init__()
        if image_channels % heads:
            raise ValueError(f"fusion: {image_channels} image channels are not divisible by {heads} heads")
        self.image_anchor, self.bev_anchor = image_anchor, bev_anchor
        dim = image_channels
        self.bev_in = nn.Conv2d(bev_channels, dim, 1) if bev_channels != dim else nn.Identity()
        self.bev_out = nn.Conv2d(dim, bev_channels, 1) if bev_channels != dim else nn.Identity()
        num_tokens = image_anchor[0] * image_anchor[1] + bev_anchor[0] * bev_anchor[1]
        self.pos = nn.Parameter(torch.zeros(1, num_tokens, dim))
        layer = nn.TransformerEncoderLayer(
            dim, heads, 4 * dim, dropout, activation="relu", batch_first=True, norm_first=True
        )
        self.transformer = nn.TransformerEncoder(layer, layers, norm=nn.LayerNorm(dim), enable_nested_tensor=False)
        nn.init.normal_(self.pos, std=0.02)

    def forward(self, image: Tensor, bev: Tensor) -> tuple[Tensor, Tensor]:
        img_tokens = F.adaptive_avg_pool2d(image, self.image_anchor)
        bev_tokens = F.adaptive_avg_pool2d(self.bev_in(bev), self.bev_anchor)
        n_img = self.image_anchor[0] * self.image_anchor[1]
        tokens = torch.cat([img_tokens.flatten(2), bev_tokens.flatten(2)], dim=2).transpose(1, 2)
        tokens = self.transformer(tokens + self.pos)
        img_out = tokens[:, :n_img].transpose(1, 2).reshape(img_tokens.shape)
        bev_out = tokens[:, n_img:].transpose(1, 2).reshape(bev_tokens.shape)
        image = image + F.interpolate(img_out, size=image.shape[-2:], mode="bilinear", align_corners=False)
        bev = bev + self.bev_out(F.interpolate(bev_out, size=bev.shape[-2:], mode="bilinear", align_corners=False))
        return image, bev
