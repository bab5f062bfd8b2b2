"""LEAD's TFv5 planning decoder (``lead/tfv6/tfv5_planning_decoder.py``) under LEAD's names.

The context holds only the speed and command tokens (the command encoder reads 6 values whatever the dataset); the
current target point, unnormalised, initialises the hidden state of two GRUs that refine the route and waypoint
queries. TFv5 always predicts route (10), waypoints and a target speed.
"""

import torch
from torch import Tensor, nn

from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_planner import (
    StatusContext,
    expected_speed,
    planning_transformer,
    scaled_cumsum,
    status_token,
    target_speed_head,
)

TFV5_COMMANDS = 6


class TFv5ContextEncoder(StatusContext):
    def __init__(self, config: LeadConfig, bev_channels: int) -> None:
        d = config.transfuser_token_dim
        super().__init__(config, bev_channels, int(config.use_velocity) + int(config.use_discrete_command))
        if config.use_discrete_command:
            self.command_encoder = nn.Sequential(nn.Linear(TFV5_COMMANDS, d))

    def forward(self, bev_features: Tensor, data: dict[str, Tensor]) -> Tensor:
        c, d = self.config, self.config.transfuser_token_dim
        like = self.dimension_adapter.weight
        status = self.speed_tokens(data)
        if c.use_discrete_command:
            status.append(status_token(self.command_encoder, data["command"].to(like.device, like.dtype), d))
        return self.context(bev_features, status)


class TFv5PlanningDecoder(nn.Module):
    def __init__(self, bev_channels: int, config: LeadConfig) -> None:
        super().__init__()
        self.config = c = config
        d, h = c.transfuser_token_dim, c.gru_hidden_size
        self.planning_context_encoder = TFv5ContextEncoder(c, bev_channels)
        self.num_route, self.num_waypoints = c.num_route_points_prediction, c.num_way_points_prediction
        self.query = nn.Parameter(torch.zeros(1, self.num_route + self.num_waypoints + 1, d))
        self.transformer_decoder = planning_transformer(c)
        self.tp_encoder = nn.Linear(2, h)
        self.route_gru = nn.GRU(input_size=d, hidden_size=h, batch_first=True)
        self.route_decoder = nn.Sequential(nn.Linear(h, 2))
        self.wp_gru = nn.GRU(input_size=d, hidden_size=h, batch_first=True)
        self.wp_decoder = nn.Sequential(nn.Linear(h, 2))
        self.target_speed_decoder = target_speed_head(d)
        nn.init.uniform_(self.query)

    def forward(
        self, bev_features: Tensor, data: dict[str, Tensor], radar: tuple[Tensor, Tensor] | None = None
    ) -> dict[str, Tensor]:
        context = self.planning_context_encoder(bev_features, data)
        values = self.transformer_decoder(self.query.repeat(context.shape[0], 1, 1), context)
        route_values = values[:, : self.num_route]
        waypoint_values = values[:, self.num_route : -1]
        like = self.tp_encoder.weight
        hidden = self.tp_encoder(data["target_point"].to(like.device, like.dtype)).unsqueeze(0)
        route_values, _ = self.route_gru(route_values, hidden)
        waypoint_values, _ = self.wp_gru(waypoint_values, hidden)
        logits = self.target_speed_decoder(values[:, -1])
        return {
            "pred_route": scaled_cumsum(self.route_decoder(route_values), self.config.trajectory_scale),
            "pred_future_waypoints": scaled_cumsum(self.wp_decoder(waypoint_values), self.config.trajectory_scale),
            "pred_target_speed_distribution": logits,
            "pred_target_speed_scalar": expected_speed(logits),
        }
