"""Model-input batches with the contract's shapes and plausible values, for model and training tests and benchmarks.

Not real data: shapes follow :class:`~lead_s2r.models.inputs.Batch` and the config, values are random but in
range (speeds below ``max_speed``, gently curving paths), so a forward/backward pass exercises every head.
"""

import torch
from torch import Tensor

from lead_s2r.models.config import TFv6Config
from lead_s2r.models.inputs import PERCEPTION_TASKS, PLANNING_TASKS, Batch

#: Targets each built-in dataset provides; what :func:`random_batch` fills in.
SOURCE_TARGETS: dict[str, frozenset[str]] = {
    "carla": PLANNING_TASKS | PERCEPTION_TASKS,
    "navsim": frozenset({"waypoints", "headings", "bev_semantic", "boxes"}),
    "wod": frozenset({"waypoints"}),
}


def random_batch(
    config: TFv6Config,
    batch_size: int,
    source: str,
    *,
    num_radar: int = 16,
    num_boxes: int = 6,
    generator: torch.Generator | None = None,
) -> Batch:
    """A batch with the contract's shapes and plausible values, for tests and benchmarks.

    Targets follow :data:`SOURCE_TARGETS` for ``source`` (unknown sources get planning targets only); inputs the
    config does not read (LiDAR for LTFv6, radar without a radar branch) are left out.
    """
    g = generator if generator is not None else torch.Generator().manual_seed(0)
    b = batch_size
    h, w = config.image_size
    hb, wb = config.bev.shape
    grid = config.trajectory_grids[source]
    targets = SOURCE_TARGETS.get(source, frozenset({"waypoints"}))
    space = config.space(source)

    def uniform(*shape: int, low: float = 0.0, high: float = 1.0) -> Tensor:
        return torch.rand(*shape, generator=g) * (high - low) + low

    def randint(high: int, *shape: int) -> Tensor:
        return torch.randint(0, high, shape, generator=g)

    def ones(*shape: int) -> Tensor:
        return torch.ones(shape, dtype=torch.bool)

    speed = uniform(b, high=config.max_speed)
    times = torch.tensor(grid.times)
    # gently curving paths: forward at the current speed, a random lateral bend
    curvature = uniform(b, 1, low=-0.05, high=0.05)
    x = speed[:, None] * times + 0.1
    batch: Batch = {
        "__key__": [f"{source}-{i:06d}" for i in range(b)],
        "rgb": uniform(b, 3, h, w, high=255.0),
        "speed": speed,
        "acceleration": uniform(b, 2, low=-2.0, high=2.0),
        "command": randint(config.num_commands, b),
        "target_points": torch.stack([uniform(b, 3, high=60.0), uniform(b, 3, low=-10.0, high=10.0)], dim=-1),
        "target_points_valid": ones(b, 3) if source == "carla" else torch.zeros(b, 3, dtype=torch.bool),
        "waypoints": torch.stack([x, 0.5 * curvature * x**2], dim=-1),
        "waypoints_valid": ones(b, grid.num_points),
    }
    if config.bev_input == "raster":
        batch["lidar_bev"] = uniform(b, config.lidar_channels, hb, wb)
    if config.use_radar:
        bev = config.bev
        radar_xy = torch.stack([uniform(b, num_radar, low=bev.x_min, high=bev.x_max), uniform(b, num_radar)], -1)
        radar_xy[..., 1] = radar_xy[..., 1] * (bev.y_max - bev.y_min) + bev.y_min
        sensor = randint(config.radar_sensors, b, num_radar, 1).float()
        z_v = uniform(b, num_radar, 2, low=-1.0, high=10.0)
        batch["radar"] = torch.cat([radar_xy, z_v, sensor], dim=-1)
        batch["radar_valid"] = uniform(b, num_radar) > 0.2
    if "headings" in targets:
        batch["headings"] = torch.atan(curvature * x)
        batch["headings_valid"] = ones(b, grid.num_points)
    if "route" in targets:
        k = config.num_route_points
        batch["route"] = torch.stack([torch.arange(1.0, k + 1).expand(b, k), uniform(b, k, low=-1.0, high=1.0)], -1)
        batch["route_valid"] = ones(b, k)
    if "target_speed" in targets:
        batch["target_speed"] = uniform(b, high=max(config.target_speed_classes) + 2.0)
        batch["target_speed_valid"] = ones(b)
    if "bev_semantic" in targets and space in config.bev_semantic_classes:
        batch["bev_semantic"] = randint(config.bev_semantic_classes[space], b, hb, wb)
    if "boxes" in targets and space in config.box_classes:
        hh, ww = hb // 4, wb // 4
        batch["box_heatmap"] = uniform(b, config.box_classes[space], hh, ww) ** 8
        batch["box_index"] = randint(hh * ww, b, num_boxes)
        batch["box_valid"] = uniform(b, num_boxes) > 0.3
        batch["box_offset"] = uniform(b, num_boxes, 2)
        batch["box_size"] = uniform(b, num_boxes, 2, low=1.0, high=5.0)
        batch["box_yaw"] = uniform(b, num_boxes, low=-3.14, high=3.14)
        batch["box_velocity"] = uniform(b, num_boxes, high=10.0)
    if "depth" in targets and space in config.depth_sources:
        batch["depth"] = uniform(b, h, w, high=config.max_depth)
    if "semantic" in targets and space in config.semantic_classes:
        batch["semantic"] = randint(config.semantic_classes[space], b, h, w)
    if "radar" in targets and config.use_radar and space in config.radar_sources:
        batch["radar_targets"] = torch.stack([uniform(b, 5, high=30.0), uniform(b, 5, low=-10.0, high=10.0)], -1)
        batch["radar_targets"] = torch.cat([batch["radar_targets"], uniform(b, 5, 1, high=10.0)], -1)
        batch["radar_targets_valid"] = uniform(b, 5) > 0.4
    return batch
