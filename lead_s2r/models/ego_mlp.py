"""Ego-status MLP: the paper's lower bound (NAVSIM's EgoStatusMLP), trajectory from speed, acceleration and command."""

from collections.abc import Collection

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lead_s2r.models.config import EgoMLPConfig, TrajectoryGrid
from lead_s2r.models.inputs import Batch


class EgoStatusMLP(nn.Module):
    """``[speed, ax, ay, command one-hot]`` -> MLP -> (x, y, heading) per waypoint, one output layer per grid."""

    def __init__(self, config: EgoMLPConfig | None = None) -> None:
        super().__init__()
        self.config = c = config if config is not None else EgoMLPConfig()
        layers: list[nn.Module] = []
        width = 3 + c.num_commands
        for _ in range(c.layers):
            layers += [nn.Linear(width, c.hidden), nn.ReLU(inplace=True)]
            width = c.hidden
        self.trunk = nn.Sequential(*layers)
        self.heads = nn.ModuleDict({s: nn.Linear(width, g.num_points * 3) for s, g in c.trajectory_grids.items()})

    def grid(self, source: str) -> TrajectoryGrid:
        return self.config.trajectory_grids[source]

    def tasks(self, source: str) -> frozenset[str]:
        return frozenset({"waypoints", "headings"}) if source in self.heads else frozenset()

    def forward(self, batch: Batch, source: str, tasks: Collection[str] | None = None) -> dict[str, Tensor]:
        c = self.config
        speed = (batch["speed"].float() / c.max_speed)[:, None]
        command = F.one_hot(batch["command"].long(), c.num_commands).float()
        status = torch.cat([speed, batch["acceleration"].float() / c.max_acceleration, command], dim=1)
        out = self.heads[source](self.trunk(status)).view(status.shape[0], -1, 3)
        return {"waypoints": out[..., :2], "headings": out[..., 2]}
