"""Planning decoder v6: learned queries for waypoints, route checkpoints and target speed attend to BEV tokens
plus status tokens (speed, acceleration, command, each target point, radar objects). No GRU.
"""

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lead_s2r.models.config import TARGET_POINT_SLOTS, TFv6Config
from lead_s2r.models.inputs import Batch


def require(batch: Batch, key: str, why: str) -> Tensor:
    """Fetch a batch entry or fail naming the key and the config option that wants it."""
    if key not in batch:
        raise KeyError(f"batch has no {key!r}, needed by {why}")
    return batch[key]  # type: ignore[literal-required]


class TargetPointNorm(nn.Module):
    """Map target points from [low, high] to [-1, 1] per axis and clamp, so far-away points cannot blow up tokens.

    The range lives in persistent buffers: a checkpoint carries the range its weights were trained with.
    """

    def __init__(self, low: tuple[float, float], high: tuple[float, float]) -> None:
        super().__init__()
        self.register_buffer("low", torch.zeros(2))
        self.register_buffer("high", torch.ones(2))
        self.set_range(low, high)

    def set_range(self, low: tuple[float, float], high: tuple[float, float]) -> None:
        if not all(h > lo for lo, h in zip(low, high, strict=True)):
            raise ValueError(f"target-point range: high {tuple(high)} must exceed low {tuple(low)} on both axes")
        with torch.no_grad():
            self.low.copy_(torch.tensor(low, dtype=torch.float32))
            self.high.copy_(torch.tensor(high, dtype=torch.float32))

    @property
    def range(self) -> tuple[tuple[float, float], tuple[float, float]]:
        low, high = self.low.tolist(), self.high.tolist()
        return (low[0], low[1]), (high[0], high[1])

    def forward(self, points: Tensor) -> Tensor:
        return (2.0 * (points.float() - self.low) / (self.high - self.low) - 1.0).clamp(-1.0, 1.0)


class StatusEncoder(nn.Module):
    """One token per ego-status input, each with its own learned position; absent target points are masked out."""

    def __init__(self, config: TFv6Config, dim: int) -> None:
        super().__init__()
        unknown = set(config.target_points) - set(TARGET_POINT_SLOTS)
        if unknown:
            raise ValueError(f"target_points entries must be among {TARGET_POINT_SLOTS}, got {sorted(unknown)}")
        self.config = config
        self.slots = [TARGET_POINT_SLOTS.index(s) for s in config.target_points]
        # an index tensor on the model's device: indexing with the list would copy it from the host every step
        self.register_buffer("slot_index", torch.tensor(self.slots, dtype=torch.long), persistent=False)
        self.speed = nn.Linear(1, dim) if config.use_speed else None
        self.acceleration = nn.Linear(2, dim) if config.use_acceleration else None
        self.command = nn.Linear(config.num_commands, dim) if config.use_command else None
        self.target_point = nn.Linear(2, dim) if self.slots else None
        self.tp_norm = TargetPointNorm(config.target_point_low, config.target_point_high)
        count = len(self.slots) + sum(m is not None for m in (self.speed, self.acceleration, self.command))
        self.pos = nn.Parameter(torch.randn(1, count, dim) * 0.02)

    def forward(self, batch: Batch) -> tuple[Tensor, Tensor]:
        """Tokens (B, S, D) and their padding mask (B, S), True = ignore."""
        c = self.config
        tokens: list[Tensor] = []
        if self.speed is not None:
            speed = require(batch, "speed", "use_speed")
            tokens.append(self.speed((speed.float() / c.max_speed)[:, None]))
        if self.acceleration is not None:
            accel = require(batch, "acceleration", "use_acceleration")
            tokens.append(self.acceleration(accel.float() / c.max_acceleration))
        if self.command is not None:
            command = require(batch, "command", "use_command")
            tokens.append(self.command(F.one_hot(command.long(), c.num_commands).float()))
        b = tokens[0].shape[0] if tokens else len(batch["speed"])
        device = self.pos.device
        pad = torch.zeros(b, len(tokens), dtype=torch.bool, device=device)
        if self.target_point is not None:
            if "target_points" in batch:
                points = self.tp_norm(batch["target_points"][:, self.slot_index])
                valid = batch["target_points_valid"][:, self.slot_index].bool()
            else:  # a source without route target points (NAVSIM, WOD): masked tokens
                points = torch.zeros(b, len(self.slots), 2, device=device)
                valid = torch.zeros(b, len(self.slots), dtype=torch.bool, device=device)
            tp_tokens = self.target_point(torch.where(valid[..., None], points, 0.0))
            tokens.extend(tp_tokens.unbind(1))
            pad = torch.cat([pad, ~valid], dim=1)
        return torch.stack(tokens, dim=1) + self.pos, pad


class PlanningDecoder(nn.Module):
    """Transformer decoder over learned queries; one waypoint query set per output grid (dataset)."""

    def __init__(self, config: TFv6Config) -> None:
        super().__init__()
        d = config.token_dim
        self.config = config
        self.status = StatusEncoder(config, d)
        self.route_queries = nn.Parameter(torch.rand(1, config.num_route_points, d) * 0.02)
        self.speed_query = nn.Parameter(torch.rand(1, 1, d) * 0.02)
        self.waypoint_queries = nn.ParameterDict(
            {
                name: nn.Parameter(torch.rand(1, grid.num_points, d) * 0.02)
                for name, grid in config.trajectory_grids.items()
            }
        )
        layer = nn.TransformerDecoderLayer(
            d, config.decoder_heads, config.decoder_ffn, config.decoder_dropout, activation="gelu", batch_first=True
        )
        self.decoder = nn.TransformerDecoder(layer, config.decoder_layers, norm=nn.LayerNorm(d))
        n_speed = len(config.target_speed_classes)
        self.speed_head = nn.Sequential(nn.Linear(d, d), nn.ReLU(inplace=True), nn.Linear(d, n_speed))
        self.register_buffer("speed_classes", torch.tensor(config.target_speed_classes), persistent=False)
        self.waypoint_head = nn.Linear(d, 2)
        self.route_head = nn.Linear(d, 2)
        self.heading_head = nn.Linear(d, 1) if config.predict_headings else None

    @property
    def tasks(self) -> frozenset[str]:
        planning = {"waypoints", "route", "target_speed"}
        return frozenset(planning | ({"headings"} if self.heading_head is not None else set()))

    def forward(
        self, bev_tokens: Tensor, batch: Batch, source: str, radar_tokens: Tensor | None = None
    ) -> dict[str, Tensor]:
        if source not in self.waypoint_queries:
            raise KeyError(
                f"no trajectory grid for source {source!r}; trajectory_grids has {sorted(self.waypoint_queries)}"
            )
        status, status_pad = self.status(batch)
        b, device = bev_tokens.shape[0], bev_tokens.device
        parts = [(bev_tokens, torch.zeros(b, bev_tokens.shape[1], dtype=torch.bool, device=device))]
        parts.append((status.to(bev_tokens.dtype), status_pad))
        if radar_tokens is not None:
            parts.append((radar_tokens, torch.zeros(b, radar_tokens.shape[1], dtype=torch.bool, device=device)))
        memory = torch.cat([tokens for tokens, _ in parts], dim=1)
        pad = torch.cat([mask for _, mask in parts], dim=1)
        k = self.config.num_route_points
        queries = torch.cat([self.route_queries, self.speed_query, self.waypoint_queries[source]], dim=1)
        out = self.decoder(queries.expand(b, -1, -1), memory, memory_key_padding_mask=pad)
        route_q, speed_q, waypoint_q = out[:, :k], out[:, k], out[:, k + 1 :]
        logits = self.speed_head(speed_q).float()
        result = {
            "target_speed_logits": logits,
            "target_speed": (logits.softmax(-1) * self.speed_classes).sum(-1),
        }
        result.update(self.trajectories(route_q, waypoint_q, batch))
        return result

    def path(self, head: nn.Module, features: Tensor, scale: float | None = None) -> Tensor:
        """The cumulative sum of ``head``'s per-step outputs, each ``scale`` units (default ``trajectory_scale`` m)."""
        return (head(features).float() * (self.config.trajectory_scale if scale is None else scale)).cumsum(1)

    def trajectories(self, route_q: Tensor, waypoint_q: Tensor, batch: Batch) -> dict[str, Tensor]:
        """Route and waypoints as cumulative sums of per-query steps; headings likewise."""
        result = {"route": self.path(self.route_head, route_q), "waypoints": self.path(self.waypoint_head, waypoint_q)}
        if self.heading_head is not None:
            result["headings"] = self.path(self.heading_head, waypoint_q, self.config.heading_scale).squeeze(-1)
        return result
