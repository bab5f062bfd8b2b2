"""Model-input batches with the contract's shapes and plausible values, for model and training tests and benchmarks.

Not real data: shapes follow :class:`~lead_s2r.models.inputs.Batch` and what the network reads
(:func:`~lead_s2r.models.input_spec.input_spec`), values are random but in range (speeds below 15 m/s, gently
curving paths, boxes on the BEV), and box labels are encoded by LEAD's own encoder, so a forward/backward pass
exercises every head the network has for the source.
"""

import numpy as np
import torch
from torch import Tensor

from lead_s2r.data.collate import collate
from lead_s2r.data.lead_centernet import lead_centernet_targets
from lead_s2r.models.input_spec import InputSpec, input_spec
from lead_s2r.models.inputs import Batch
from lead_s2r.models.lead_driver import LeadDriver


def random_batch(
    driver: LeadDriver, batch_size: int, source: str, *, num_radar: int = 16, generator: torch.Generator | None = None
) -> Batch:
    """A batch of ``source`` with every input the network reads and a label for each of its tasks for ``source``."""
    g = generator if generator is not None else torch.Generator().manual_seed(0)
    spec, tasks, b = input_spec(driver.config), driver.tasks(source), batch_size
    h, w = spec.image_size
    hb, wb = spec.bev.shape
    grid = spec.trajectory_grids[source]

    def uniform(*shape: int, low: float = 0.0, high: float = 1.0) -> Tensor:
        return torch.rand(*shape, generator=g) * (high - low) + low

    def ones(*shape: int) -> Tensor:
        return torch.ones(shape, dtype=torch.bool)

    speed = uniform(b, high=15.0)
    curvature = uniform(b, 1, low=-0.05, high=0.05)
    x = speed[:, None] * torch.tensor(grid.times) + 0.1
    batch: Batch = {
        "__key__": [f"{source}-{i:06d}" for i in range(b)],
        "rgb": uniform(b, 3, h, w, high=255.0),
        "speed": speed,
        "acceleration": uniform(b, 2, low=-2.0, high=2.0),
        "command": torch.randint(0, 4, (b,), generator=g),
        "target_points": torch.stack([uniform(b, 3, high=60.0), uniform(b, 3, low=-10.0, high=10.0)], dim=-1),
        "target_points_valid": ones(b, 3),
        "waypoints": torch.stack([x, 0.5 * curvature * x**2], dim=-1),
        "waypoints_valid": ones(b, grid.num_points),
    }
    if spec.lidar_raster:
        batch["lidar_bev"] = torch.randint(0, 6, (b, 1, hb, wb), dtype=torch.uint8, generator=g)
    if spec.radar:
        xy = torch.stack([uniform(b, num_radar, low=0.0, high=spec.bev.x_max), uniform(b, num_radar, low=-20, high=20)])
        sensor = torch.randint(0, 4, (b, num_radar, 1), generator=g).float()
        batch["radar"] = torch.cat([xy.permute(1, 2, 0), uniform(b, num_radar, 2, low=-1.0, high=10.0), sensor], -1)
        batch["radar_valid"] = uniform(b, num_radar) > 0.2
    if "headings" in tasks:
        batch["headings"] = torch.atan(curvature * x)
        batch["headings_valid"] = ones(b, grid.num_points)
    if "route" in tasks:
        k = spec.num_route_points
        batch["route"] = torch.stack([torch.arange(1.0, k + 1).expand(b, k), uniform(b, k, low=-1.0, high=1.0)], -1)
        batch["route_valid"] = ones(b, k)
    if "target_speed" in tasks:
        batch["target_speed"] = uniform(b, high=22.0)
        batch["target_speed_valid"] = ones(b)
    if "bev_semantic" in tasks:
        batch["bev_semantic"] = torch.randint(0, spec.bev_semantic_classes[source], (b, hb, wb), generator=g)
    if "lead_boxes" in tasks:
        batch.update(collate([random_boxes(spec.lead_box_classes[source], spec, source, g) for _ in range(b)]))
    if "depth" in tasks:
        batch["depth"] = uniform(b, h, w, high=spec.max_depth)
    if "semantic" in tasks:
        batch["semantic"] = torch.randint(0, spec.semantic_classes[source], (b, h, w), generator=g)
    if "radar" in tasks:
        targets = torch.stack([uniform(b, 5, high=30.0), uniform(b, 5, low=-10.0, high=10.0), uniform(b, 5, high=10)])
        batch["radar_targets"] = targets.permute(1, 2, 0)
        batch["radar_targets_valid"] = uniform(b, 5) > 0.4
    return batch


def random_boxes(num_classes: int, spec: InputSpec, source: str, g: torch.Generator) -> dict[str, Tensor]:
    """LEAD's CenterNet targets of three random boxes on the BEV (classes below ``num_classes``)."""
    bev = spec.bev
    rows = torch.rand(3, 10, generator=g).numpy().astype(np.float64)
    boxes = np.zeros((3, 10), np.float32)
    boxes[:, 0] = bev.x_min + rows[:, 0] * (bev.x_max - bev.x_min)
    boxes[:, 1] = bev.y_min + rows[:, 1] * (bev.y_max - bev.y_min)
    boxes[:, 3:5] = 1.0 + 4.0 * rows[:, 3:5]
    boxes[:, 6] = (rows[:, 6] - 0.5) * 6.0
    boxes[:, 7] = 5.0 * rows[:, 7]
    classes = np.floor(rows[:, 9] * num_classes).astype(np.int64)
    return lead_centernet_targets(boxes, classes, bev, num_classes, spec.lead_yaw_bins, velocity=source == "carla")
