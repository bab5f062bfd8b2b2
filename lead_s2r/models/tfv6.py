"""TFv6 / LTFv6 / TFv5: backbone, planning decoder, radar detector and per-label-space auxiliary heads."""

from collections.abc import Collection

from torch import Tensor, nn

from lead_s2r.models.backbone import TransfuserBackbone
from lead_s2r.models.config import TFv6Config, TrajectoryGrid
from lead_s2r.models.embeddings import grid_embedding, sine_embedding
from lead_s2r.models.heads import BEVSemanticHead, CenterNetHead, PerspectiveHead
from lead_s2r.models.inputs import PLANNING_TASKS, Batch
from lead_s2r.models.planning_decoder import PlanningDecoder
from lead_s2r.models.radar import RadarDetector
from lead_s2r.models.tfv5_decoder import TFv5Decoder


class TFv6(nn.Module):
    """The LEAD TransFuser v6 family as one plain module; the config picks TFv6, LTFv6 or the TFv5 decoder.

    ``forward(batch, source, tasks)`` computes only what ``tasks`` need (default: everything the model can do for
    ``source``), so a source that supervises perception alone does not pay for the planner.
    """

    def __init__(self, config: TFv6Config | None = None) -> None:
        super().__init__()
        self.config = c = config if config is not None else TFv6Config()
        d = c.token_dim
        self.backbone = TransfuserBackbone(c)
        self.bev_tokens = nn.Conv2d(self.backbone.bev_channels, d, 1)
        self.planner = TFv5Decoder(c) if c.decoder == "v5" else PlanningDecoder(c)
        self.radar = None
        if c.use_radar:
            self.radar = RadarDetector(
                c.bev, c.bev_feature_channels, d, c.radar_sensors, c.radar_queries, c.radar_layers,
                c.decoder_heads, c.radar_ffn, c.decoder_dropout, c.max_speed,
            )  # fmt: skip
            self.radar_tokens = nn.Linear(d, d)
        g = c.bev_feature_channels
        self.bev_semantic = nn.ModuleDict({s: BEVSemanticHead(g, n) for s, n in c.bev_semantic_classes.items()})
        self.boxes = nn.ModuleDict({s: CenterNetHead(g, n, c.box_yaw_bins) for s, n in c.box_classes.items()})
        spaces = sorted(set(c.semantic_classes) | set(c.depth_sources))
        self.perspective = nn.ModuleDict(
            {
                s: PerspectiveHead(
                    self.backbone.image_channels, c.semantic_classes.get(s), s in c.depth_sources, c.max_depth
                )
                for s in spaces
            }
        )

    @property
    def camera_select(self) -> nn.Module:
        """The camera ablation crop; losses apply it to perspective labels too."""
        return self.backbone.cameras

    @property
    def reads_target_points(self) -> bool:
        """Whether route target points reach the planner (as tokens, or as TFv5's GRU initialisation)."""
        return bool(self.config.target_points) or self.config.decoder == "v5"

    @property
    def target_speed_classes(self) -> Tensor:
        """The planner's target-speed bins (m/s), on its device: the target-speed loss encodes labels on them."""
        return self.planner.speed_classes

    @property
    def radar_scale(self) -> tuple[float, float, float]:
        """What the radar detection loss divides (x, y, speed) by: the BEV's half extents and the maximum speed."""
        bev = self.config.bev
        return (bev.x_max - bev.x_min) / 2, (bev.y_max - bev.y_min) / 2, self.config.max_speed

    @property
    def target_point_range(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """``(low, high)`` the planner normalises target points by (saved in the state dict)."""
        return self.planner.status.tp_norm.range

    def set_target_point_range(self, low: tuple[float, float], high: tuple[float, float]) -> None:
        self.planner.status.tp_norm.set_range(low, high)

    def grid(self, source: str) -> TrajectoryGrid:
        return self.config.trajectory_grids[source]

    def tasks(self, source: str) -> frozenset[str]:
        """Loss terms this model can produce for ``source``."""
        c, space = self.config, self.config.space(source)
        tasks = set(self.planner.tasks) if source in c.trajectory_grids else set()
        if space in self.bev_semantic:
            tasks.add("bev_semantic")
        if space in self.boxes:
            tasks.add("boxes")
        if space in c.depth_sources:
            tasks.add("depth")
        if space in c.semantic_classes:
            tasks.add("semantic")
        if self.radar is not None and space in c.radar_sources:
            tasks.add("radar")
        return frozenset(tasks)

    def forward(self, batch: Batch, source: str, tasks: Collection[str] | None = None) -> dict[str, Tensor]:
        available = self.tasks(source)
        tasks = available if tasks is None else frozenset(tasks)
        if tasks - available:
            raise ValueError(f"TFv6 cannot produce {sorted(tasks - available)} for source {source!r}")
        space = self.config.space(source)
        features = self.backbone(batch["rgb"], batch.get("lidar_bev"))
        bev = self.bev_tokens(features.bev)
        pos = grid_embedding(bev.shape[-2], bev.shape[-1], bev.shape[1], bev.device).to(bev.dtype)
        bev_tokens = bev.flatten(2).transpose(1, 2) + pos
        out: dict[str, Tensor] = {}
        needs_planner = bool(tasks & PLANNING_TASKS)
        radar_tokens = None
        if self.radar is not None and "radar" in batch and (needs_planner or "radar" in tasks):
            radar = self.radar(batch["radar"], batch["radar_valid"], features.bev_grid, bev_tokens, batch["speed"])
            # detached: planning trains the radar encoder, never the detection head
            xy = self.radar.normalised(radar["radar_xy"].detach()).clamp(0, 1)
            feats = radar.pop("radar_features")
            radar_tokens = self.radar_tokens(feats) + sine_embedding(xy, feats.shape[-1]).to(feats.dtype)
            out.update(radar)
        if needs_planner:
            out.update(self.planner(bev_tokens, batch, source, radar_tokens))
        if "bev_semantic" in tasks:
            out.update(self.bev_semantic[space](features.bev_grid))
        if "boxes" in tasks:
            out.update(self.boxes[space](features.bev_grid))
        if tasks & {"depth", "semantic"}:
            out.update(self.perspective[space](features.image))
        return out


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
