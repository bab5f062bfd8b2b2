"""LEAD's TFv6 planning decoder (``lead/tfv6/planning_decoder.py``) under LEAD's names.

Context = 1x1-conv BEV tokens plus a normalised 2-D sine embedding (row-major), then status tokens in the order
velocity, acceleration, command, target point, previous, next (those used), radar queries, plus a learned status
embedding. Learned queries (route 10, waypoints ``num_way_points_prediction``, target speed 1; only those predicted)
go through PyTorch's ``nn.TransformerDecoder`` with its defaults (post-norm, feed-forward 2048 whatever the token dim,
GELU) and a final LayerNorm. Route, waypoints and headings are cumulative sums of per-query outputs.
"""

import torch
from torch import Tensor, nn

from lead_s2r.models.lead_config import TARGET_SPEED_CLASSES, LeadConfig
from lead_s2r.models.lead_embeddings import grid_sine_embedding, point_sine_embedding, unit_bev_points


def expected_speed(logits: Tensor, classes: tuple[float, ...] = TARGET_SPEED_CLASSES) -> Tensor:
    """Target-speed logits (B, C) -> softmax-weighted class speed (B,), m/s, in float32."""
    probabilities = torch.softmax(logits.float(), dim=-1)
    return (probabilities * torch.tensor(classes, device=logits.device, dtype=probabilities.dtype)[None]).sum(-1)


def scaled_cumsum(steps: Tensor, scale: float) -> Tensor:
    """Per-query steps (B, Q, C) -> their running sum over the queries, ``scale`` units of the output per unit of a
    step (1.0, LEAD's network: a multiplication by 1 is exact, so its outputs stay bit for bit LEAD's)."""
    return torch.cumsum(steps * scale, 1)


def planning_transformer(config: LeadConfig) -> nn.TransformerDecoder:
    d = config.transfuser_token_dim
    layer = nn.TransformerDecoderLayer(
        d, config.transfuser_num_bev_cross_attention_heads, activation=nn.GELU(), batch_first=True
    )
    return nn.TransformerDecoder(
        layer, num_layers=config.transfuser_num_bev_cross_attention_layers, norm=nn.LayerNorm(d)
    )


def target_speed_head(dim: int) -> nn.Sequential:
    """LEAD's target-speed classifier on one query (TFv6's and TFv5's planners alike): Linear, ReLU, Linear."""
    return nn.Sequential(nn.Linear(dim, dim), nn.ReLU(inplace=True), nn.Linear(dim, len(TARGET_SPEED_CLASSES)))


def status_token(encoder: nn.Module, value: Tensor, dim: int) -> Tensor:
    return encoder(value).reshape(-1, 1, dim)


class StatusContext(nn.Module):
    """BEV tokens + sine embedding, then the status tokens (shared by the TFv6 and TFv5 context encoders)."""

    def __init__(self, config: LeadConfig, bev_channels: int, num_status_tokens: int) -> None:
        super().__init__()
        self.config = config
        d = config.transfuser_token_dim
        self.status_pos_embedding = nn.Parameter(torch.zeros(1, num_status_tokens, d))
        self.dimension_adapter = nn.Conv2d(bev_channels, d, kernel_size=1)
        nn.init.uniform_(self.status_pos_embedding)
        if config.use_velocity:
            self.velocity_encoder = nn.Sequential(nn.Linear(1, d))

    def speed_tokens(self, data: dict[str, Tensor]) -> list[Tensor]:
        """The first status token, speed / ``max_speed`` (x ``status_scale``), when the config has one."""
        config = self.config
        if not config.use_velocity:
            return []
        like = self.dimension_adapter.weight
        speed = data["speed"].reshape(-1, 1).to(like.device, like.dtype) / config.max_speed * config.status_scale
        return [status_token(self.velocity_encoder, speed, config.transfuser_token_dim)]

    def context(self, bev_features: Tensor, status: list[Tensor]) -> Tensor:
        if not status:
            raise ValueError("LEAD's planner needs at least one status token (its context is never flattened without)")
        tokens = self.dimension_adapter(bev_features)
        tokens = tokens + grid_sine_embedding(tokens)
        tokens = torch.flatten(tokens, start_dim=2).permute(0, 2, 1)
        return torch.cat([tokens, torch.cat(status, dim=1) + self.status_pos_embedding], dim=1)


class PlanningContextEncoder(StatusContext):
    """Speed / acceleration / command / target points / radar queries -> tokens after the BEV tokens."""

    def __init__(self, config: LeadConfig, bev_channels: int) -> None:
        c, d = config, config.transfuser_token_dim
        slots = int(c.use_velocity) + int(c.use_acceleration) + int(c.use_discrete_command) + len(c.target_point_slots)
        slots += c.num_radar_queries if c.planner_radar_tokens else 0
        super().__init__(c, bev_channels, slots)
        if c.use_acceleration:
            self.acceleration_encoder = nn.Sequential(nn.Linear(1, d))
        if c.use_discrete_command:
            self.command_encoder = nn.Sequential(nn.Linear(c.discrete_command_dim, d))
        if c.use_tp:
            self.tp_encoder = nn.Linear(2, d)
        if c.planner_radar_tokens:
            self.radar_encoder = nn.Linear(c.radar_token_dim, d)

    def forward(
        self, bev_features: Tensor, data: dict[str, Tensor], radar: tuple[Tensor, Tensor] | None = None
    ) -> Tensor:
        c, d = self.config, self.config.transfuser_token_dim
        like = self.dimension_adapter.weight
        status = self.speed_tokens(data)
        if c.use_acceleration:
            acceleration = data["acceleration"].reshape(-1, 1).to(like.device, like.dtype)
            acceleration = acceleration / c.max_acceleration * c.status_scale
            status.append(status_token(self.acceleration_encoder, acceleration, d))
        if c.use_discrete_command:
            status.append(status_token(self.command_encoder, data["command"].to(like.device, like.dtype), d))
        if c.use_tp:
            scale = torch.tensor(c.target_points_normalization_constants, device=like.device, dtype=like.dtype)
            for key in c.target_point_slots:
                status.append(status_token(self.tp_encoder, data[key].to(like.device, like.dtype) / scale, d))
        if c.planner_radar_tokens:
            if radar is None:
                raise KeyError("this LEAD planner reads radar queries: it needs CARLA data and the radar detector")
            features, predictions = radar
            tokens = self.radar_encoder(features).reshape(-1, c.num_radar_queries, d)
            xy = unit_bev_points(predictions[..., :2].reshape(-1, 2), *c.bev_extent)
            status.append(tokens + point_sine_embedding(xy, d).reshape(tokens.shape))
        return self.context(bev_features, status)


class PlanningDecoder(nn.Module):
    """TFv6's transformer planner: returns route, waypoints, target-speed logits and scalar, headings (or None)."""

    def __init__(self, bev_channels: int, config: LeadConfig) -> None:
        super().__init__()
        self.config = c = config
        d = c.transfuser_token_dim
        self.planning_context_encoder = PlanningContextEncoder(c, bev_channels)
        self.num_route = c.num_route_points_prediction if c.predict_spatial_path else 0
        self.num_waypoints = c.num_way_points_prediction if c.predict_temporal_spatial_waypoints else 0
        num_queries = self.num_route + self.num_waypoints + int(c.predict_target_speed)
        self.query = nn.Parameter(torch.zeros(1, num_queries, d))
        self.transformer_decoder = planning_transformer(c)
        if c.predict_spatial_path:
            self.route_decoder = nn.Linear(d, 2)
        if c.predict_temporal_spatial_waypoints:
            self.wp_decoder = nn.Linear(d, 2)
            if c.use_navsim_data:
                self.heading_decoder = nn.Linear(d, 1)
        if c.predict_target_speed:
            self.target_speed_decoder = target_speed_head(d)
        nn.init.uniform_(self.query)

    def forward(
        self, bev_features: Tensor, data: dict[str, Tensor], radar: tuple[Tensor, Tensor] | None = None
    ) -> dict[str, Tensor]:
        c = self.config
        context = self.planning_context_encoder(bev_features, data, radar)
        queries = self.transformer_decoder(self.query.repeat(context.shape[0], 1, 1), context)
        out: dict[str, Tensor] = {}
        if self.num_route:
            out["pred_route"] = scaled_cumsum(self.route_decoder(queries[:, : self.num_route]), c.trajectory_scale)
        if self.num_waypoints:
            waypoint_queries = queries[:, self.num_route : self.num_route + self.num_waypoints]
            out["pred_future_waypoints"] = scaled_cumsum(self.wp_decoder(waypoint_queries), c.trajectory_scale)
            if c.use_navsim_data:
                headings = scaled_cumsum(self.heading_decoder(waypoint_queries), c.heading_scale)
                out["pred_headings"] = headings.squeeze(-1)
        if self.config.predict_target_speed:
            logits = self.target_speed_decoder(queries[:, self.num_route + self.num_waypoints])
            out["pred_target_speed_distribution"] = logits
            out["pred_target_speed_scalar"] = expected_speed(logits)
        return out
