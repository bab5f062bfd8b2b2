"""Radar detector: radar points become tokens, learned queries decode object-level detections.

Its query features are the radar tokens of the planning decoder (the paper's object-level radar input).
"""

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lead_s2r.models.config import BEVGrid
from lead_s2r.models.embeddings import sine_embedding


class RadarDetector(nn.Module):
    """Decode ``queries`` detections (x, y, speed, validity logit) from radar point tokens and BEV context.

    A point token = MLP(BEV feature sampled at the point, speed / max_speed, one-hot sensor) + sine position.
    """

    def __init__(
        self,
        bev: BEVGrid,
        bev_channels: int,
        dim: int,
        sensors: int = 4,
        queries: int = 20,
        layers: int = 4,
        heads: int = 8,
        ffn: int = 1024,
        dropout: float = 0.1,
        max_speed: float = 20.0,
    ) -> None:
        super().__init__()
        self.bev, self.sensors, self.max_speed, self.dim = bev, sensors, max_speed, dim
        self.point_mlp = nn.Sequential(
            nn.Linear(bev_channels + 1 + sensors, ffn), nn.ReLU(inplace=True), nn.Linear(ffn, dim)
        )
        self.speed_token = nn.Linear(1, dim)
        self.queries = nn.Parameter(torch.empty(1, queries, dim).uniform_(-1.0, 1.0) * 0.02)
        layer = nn.TransformerDecoderLayer(dim, heads, ffn, dropout, activation="gelu", batch_first=True)
        self.decoder = nn.TransformerDecoder(layer, layers, norm=nn.LayerNorm(dim))
        self.out = nn.Linear(dim, 4)  # x, y, speed, validity logit
        # output box: built once, so the forward pass copies nothing from the host
        centre = [(bev.x_min + bev.x_max) / 2, (bev.y_min + bev.y_max) / 2]
        half = [(bev.x_max - bev.x_min) / 2, (bev.y_max - bev.y_min) / 2]
        self.register_buffer("centre", torch.tensor(centre), persistent=False)
        self.register_buffer("half_extent", torch.tensor(half), persistent=False)

    def normalised(self, xy: Tensor) -> Tensor:
        """Metres -> [0, 1] over the BEV extent, per axis (x along H, y along W)."""
        b = self.bev
        return torch.stack(
            [(xy[..., 0] - b.x_min) / (b.x_max - b.x_min), (xy[..., 1] - b.y_min) / (b.y_max - b.y_min)], -1
        )

    def forward(
        self, radar: Tensor, radar_valid: Tensor, bev_grid: Tensor, bev_tokens: Tensor, speed: Tensor
    ) -> dict[str, Tensor]:
        uv = self.normalised(radar[..., :2])
        # grid_sample wants (W, H) order in [-1, 1]
        sample_at = (uv.flip(-1) * 2.0 - 1.0).unsqueeze(2).to(bev_grid.dtype)
        features = F.grid_sample(bev_grid, sample_at, mode="bilinear", align_corners=False).squeeze(-1).transpose(1, 2)
        sensor = F.one_hot(radar[..., 4].long().clamp(0, self.sensors - 1), self.sensors).to(features.dtype)
        point_in = torch.cat([features, (radar[..., 3:4] / self.max_speed).to(features.dtype), sensor], dim=-1)
        points = self.point_mlp(point_in) + sine_embedding(uv.clamp(0, 1), self.dim).to(features.dtype)
        speed_token = self.speed_token((speed / self.max_speed)[:, None, None].to(points.dtype))
        memory = torch.cat([bev_tokens, speed_token, points], dim=1)
        pad = torch.cat(
            [
                torch.zeros(memory.shape[0], bev_tokens.shape[1] + 1, dtype=torch.bool, device=memory.device),
                ~radar_valid,
            ],
            dim=1,
        )
        q = self.decoder(self.queries.expand(memory.shape[0], -1, -1), memory, memory_key_padding_mask=pad)
        raw = self.out(q).float()
        return {
            "radar_xy": torch.tanh(raw[..., :2]) * self.half_extent + self.centre,
            "radar_speed": (torch.tanh(raw[..., 2]) + 1.0) / 2.0 * self.max_speed,
            "radar_logit": raw[..., 3],
            "radar_features": q,
        }
