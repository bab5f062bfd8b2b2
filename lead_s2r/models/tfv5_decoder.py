"""TFv5 planning decoder (ablation): the v6 query transformer, but route and waypoints come from GRUs whose hidden
state is initialised with the single current target point, as in TransFuser++.

As in LEAD's ``tfv5_planning_decoder``, the target point reaches the planner only through the GRU initialisation:
the decoder context holds speed and command tokens, never a target-point token, or the GRU / one-target-point
ablations would compare a model that sees the point twice. LEAD feeds the point in metres; here it goes through the
same range normalisation as TFv6's tokens (``target_point_low/high``, resolved from the training data).
"""

import torch
from torch import Tensor, nn

from lead_s2r.models.config import TFv6Config
from lead_s2r.models.inputs import Batch
from lead_s2r.models.planning_decoder import PlanningDecoder


class TFv5Decoder(PlanningDecoder):
    """GRU refinement over the decoded query features; no headings."""

    def __init__(self, config: TFv6Config) -> None:
        if config.target_points:
            raise ValueError(
                "TFv5's decoder context holds no target-point tokens (its GRUs read the current target point); "
                f"set target_points=() instead of {config.target_points}"
            )
        if config.predict_headings:
            raise ValueError("TFv5 predicts no headings; set predict_headings=False")
        super().__init__(config)
        h = config.gru_hidden
        self.init_hidden = nn.Linear(2, h)
        self.route_gru = nn.GRU(config.token_dim, h, batch_first=True)
        self.waypoint_gru = nn.GRU(config.token_dim, h, batch_first=True)
        self.waypoint_head = nn.Linear(h, 2)
        self.route_head = nn.Linear(h, 2)

    def trajectories(self, route_q: Tensor, waypoint_q: Tensor, batch: Batch) -> dict[str, Tensor]:
        if "target_points" in batch:
            point = self.status.tp_norm(batch["target_points"][:, 1])
            point = torch.where(batch["target_points_valid"][:, 1:2].bool(), point, 0.0)
        else:
            point = torch.zeros(route_q.shape[0], 2, device=route_q.device)
        hidden = self.init_hidden(point.to(route_q.dtype))[None]
        route, _ = self.route_gru(route_q, hidden)
        waypoints, _ = self.waypoint_gru(waypoint_q, hidden)
        return {"route": self.path(self.route_head, route), "waypoints": self.path(self.waypoint_head, waypoints)}
