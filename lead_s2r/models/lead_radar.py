"""LEAD's radar detector (``lead/tfv6/radar_detector.py``) under LEAD's names: learned queries cross-attend to BEV
tokens, an ego-speed token and one token per radar point, and decode (x, y, v, validity logit) per query.

Quirk kept on purpose (LEAD's released weights learned with it): each radar point samples the BEV map with ego y on
the grid's width axis and ego x on its height axis, although BEV rows are y and columns x, so points are sampled at
transposed positions. Zero padding points are not masked either.
"""

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_embeddings import point_sine_embedding, unit_bev_points

#: Columns of LEAD's (B, 300, 5) radar input (``RadarDataIndex``).
RADAR_X, RADAR_Y, RADAR_V, RADAR_SENSOR = 0, 1, 3, 4


class RadarDetector(nn.Module):
    """(stride-32 BEV map, radar points, speed) -> (query features (B, Q, D), predictions (B, Q, 4))."""

    def __init__(self, bev_channels: int, config: LeadConfig) -> None:
        super().__init__()
        self.config = c = config
        d = c.radar_token_dim
        self.bev_proj = nn.Conv2d(bev_channels, d, kernel_size=1)
        self.ego_vel_proj = nn.Linear(1, d)
        self.radar_point_tokenizer = nn.Sequential(
            nn.Linear(d + 1 + c.num_radar_sensors, c.radar_hidden_dim_tokenizer),
            nn.ReLU(inplace=True),
            nn.Linear(c.radar_hidden_dim_tokenizer, d),
        )
        self.bev_pos_embed = nn.Parameter(torch.zeros(1, c.lidar_horz_anchors * c.lidar_vert_anchors, d))
        self.ego_vel_pos_embed = nn.Parameter(torch.zeros(1, 1, d))
        self.q = nn.Parameter(torch.zeros(1, c.num_radar_queries, d))
        layer = nn.TransformerDecoderLayer(
            d_model=d,
            nhead=c.radar_num_heads,
            dim_feedforward=c.radar_tf_dim_ff,
            dropout=c.radar_dropout,
            activation=nn.GELU(),
            batch_first=True,
        )
        self.tf = nn.TransformerDecoder(layer, num_layers=c.radar_num_layers, norm=nn.LayerNorm(d))
        nn.init.xavier_uniform_(self.q)
        self.state_decoder = nn.Sequential(
            nn.Linear(d, c.radar_hidden_dim_decoder), nn.ReLU(inplace=True), nn.Linear(c.radar_hidden_dim_decoder, 3)
        )
        self.label_decoder = nn.Linear(d, 1)

    def sample_bev(self, bev: Tensor, xy: Tensor) -> Tensor:
        """Bilinear BEV features at (B, N, 2) points in metres, with LEAD's transposed axes (module docstring)."""
        (x0, x1), (y0, y1) = self.config.bev_extent
        u = 2 * (xy[..., 1] - y0) / (y1 - y0) - 1
        v = 2 * (xy[..., 0] - x0) / (x1 - x0) - 1
        grid = torch.stack([u, v], dim=-1).view(xy.shape[0], xy.shape[1], 1, 2)
        return F.grid_sample(bev, grid, mode="bilinear", align_corners=True).squeeze(-1).permute(0, 2, 1)

    def tokenize(self, bev: Tensor, radar: Tensor) -> Tensor:
        c = self.config
        xy = radar[..., : RADAR_Y + 1]
        sensors = F.one_hot(radar[..., RADAR_SENSOR].to(torch.int64), num_classes=c.num_radar_sensors).to(bev.dtype)
        velocity = radar[..., RADAR_V : RADAR_V + 1] / c.max_speed
        tokens = self.radar_point_tokenizer(torch.cat([self.sample_bev(bev, xy), velocity, sensors], dim=-1))
        flat = xy.reshape(-1, 2)
        embedding = point_sine_embedding(unit_bev_points(flat, *c.bev_extent), c.radar_token_dim)
        return tokens + embedding.reshape(tokens.shape)

    def forward(self, bev_features: Tensor, radar: Tensor, speed: Tensor) -> tuple[Tensor, Tensor]:
        c = self.config
        bev = self.bev_proj(bev_features)
        ego = self.ego_vel_proj(speed.reshape(-1, 1) / c.max_speed).unsqueeze(1)
        radar_tokens = self.tokenize(bev, radar)
        bev_tokens = bev.flatten(2).permute(0, 2, 1) + self.bev_pos_embed
        kv = torch.cat([bev_tokens, ego + self.ego_vel_pos_embed, radar_tokens], dim=1)
        features = self.tf(self.q.repeat(kv.shape[0], 1, 1), kv)
        state = self.state_decoder(features)
        (x0, x1), (y0, y1) = c.bev_extent
        x = torch.tanh(state[..., 0]) * ((x1 - x0) / 2) + (x1 + x0) / 2
        y = torch.tanh(state[..., 1]) * ((y1 - y0) / 2) + (y1 + y0) / 2
        v = (torch.tanh(state[..., 2]) + 1) / 2 * c.max_speed
        predictions = torch.cat([torch.stack([x, y, v], dim=-1), self.label_decoder(features)], dim=-1)
        return features, predictions
