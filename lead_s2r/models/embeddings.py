"""Sine positional embeddings for BEV cells and points (DETR style), shared by the decoders and the radar branch."""

import math

import torch
from torch import Tensor


def sine_embedding(coords: Tensor, dim: int, temperature: float = 10000.0) -> Tensor:
    """Embed coordinates ``(..., 2)`` in [0, 1] into ``(..., dim)``: half the channels per axis, sin/cos pairs."""
    if dim % 4:
        raise ValueError(f"sine embedding dim must be divisible by 4, got {dim}")
    quarter = dim // 4
    freqs = temperature ** (torch.arange(quarter, device=coords.device, dtype=torch.float32) / quarter)
    angles = coords.float()[..., None] * (2 * math.pi) / freqs  # (..., 2, quarter)
    return torch.cat([angles.sin(), angles.cos()], dim=-1).flatten(-2)  # (..., 2 * dim / 2)


def grid_embedding(height: int, width: int, dim: int, device: torch.device | None = None) -> Tensor:
    """Sine embedding of the cell centres of an ``height x width`` grid, flattened row-major: ``(H * W, dim)``."""
    rows = (torch.arange(height, device=device, dtype=torch.float32) + 0.5) / height
    cols = (torch.arange(width, device=device, dtype=torch.float32) + 0.5) / width
    grid = torch.stack(torch.meshgrid(rows, cols, indexing="ij"), dim=-1)
    return sine_embedding(grid.reshape(-1, 2), dim)
