"""The sine embeddings LEAD's planner and radar detector use, in LEAD's operation order so outputs match bit for bit."""

import math

import torch
from torch import Tensor


def point_sine_embedding(points: Tensor, dim: int) -> Tensor:
    """(..., 2) points in [0, 1] -> (..., dim) DAB-DETR sine embedding, y first (``gen_sineembed_for_position``)."""
    half = dim // 2
    dim_t = torch.arange(half, dtype=torch.float32, device=points.device)
    dim_t = 10000 ** (2 * (dim_t // 2) / half)
    pos_x = points[..., 0] * (2 * math.pi)
    pos_y = points[..., 1] * (2 * math.pi)

    def interleave(p: Tensor) -> Tensor:
        p = p[..., None] / dim_t
        return torch.stack((p[..., 0::2].sin(), p[..., 1::2].cos()), dim=-1).flatten(-2)

    return torch.cat((interleave(pos_y), interleave(pos_x)), dim=-1)


def unit_bev_points(points: Tensor, x_range: tuple[float, float], y_range: tuple[float, float]) -> Tensor:
    """Metres in LEAD's ego frame -> [0, 1] over the BEV extent, per axis."""
    x = (points[..., 0] - x_range[0]) / (x_range[1] - x_range[0])
    y = (points[..., 1] - y_range[0]) / (y_range[1] - y_range[0])
    return torch.stack([x, y], dim=-1)


def grid_sine_embedding(like: Tensor) -> Tensor:
    """(B, D, H, W) -> DETR's normalised 2-D sine embedding of the grid positions, (B, D, H, W): D/2 channels for the
    row coordinate, then D/2 for the column coordinate (``PositionEmbeddingSine(normalize=True)``), which is
    :func:`point_sine_embedding` of the cells' (column, row) positions scaled into (0, 1)."""
    bs, d, h, w = like.shape
    ones = torch.ones((bs, h, w), device=like.device)
    y_embed = ones.cumsum(1, dtype=torch.float32)
    x_embed = ones.cumsum(2, dtype=torch.float32)
    eps = 1e-6
    points = torch.stack([x_embed / (x_embed[:, :, -1:] + eps), y_embed / (y_embed[:, -1:, :] + eps)], dim=-1)
    return point_sine_embedding(points, d).permute(0, 3, 1, 2).to(like.dtype).contiguous()
