"""The one place where our ISO ego frame (x forward, y LEFT) meets LEAD's (x forward, y RIGHT).

Nothing else in the package flips y: :func:`to_lead_inputs` and :func:`from_lead_outputs` are the only crossings.

- Lateral coordinates (target points, radar, predicted waypoints and route) change sign; headings change sign.
- The LiDAR raster: ours has rows along +x and columns along +y (left); LEAD's has rows along its y (left to right,
  i.e. row 0 is the leftmost) and columns along x (back to front), so LEAD's raster is ours transposed with its rows
  reversed. Both grids are symmetric in y, so no cell moves off the grid (a point exactly on a cell edge lands in
  the cell beside LEAD's, as both rasters take half-open cells in their own y direction).
- Commands: our ids become LEAD's one-hot in NAVSIM's, CARLA's (RoadOption - 1) or WOD-E2E's intent order (the
  tables below; WOD-E2E's is read only with ``use_discrete_command``, off by LEAD's WOD-E2E default).
- Speed stays m/s and acceleration becomes the norm of our (ax, ay): LEAD's network normalises both itself.
- CenterNet maps: LEAD's sub-cell lateral offset is measured from the cell's other edge and its yaw bins turn the
  other way; :func:`boxes_from_lead` turns them into ours (``lead_s2r.data.lead_centernet`` encodes our labels).
- Radar: LEAD's (B, 300, 5) is sensor-major, 75 rows per sensor, points outside its BEV dropped and missing rows
  zero with the sensor id kept; LEAD does not mask them, so the padding rows' ids matter and are rebuilt here.
"""

import torch
from torch import Tensor

from lead_s2r.models.inputs import Batch, lidar_input
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.schema import Command

#: Our 4-way command id -> index in LEAD's NAVSIM one-hot.
NAVSIM_COMMAND_INDEX = {Command.LEFT: 0, Command.STRAIGHT: 1, Command.RIGHT: 2, Command.UNKNOWN: 3}
#: Our full command (a 4-way one is one of them) -> LEAD's CARLA one-hot (RoadOption - 1; unknown -> lane follow, as
#: LEAD's ``command_to_one_hot``).
CARLA_FULL_COMMAND_INDEX = {
    Command.LEFT: 0,
    Command.RIGHT: 1,
    Command.STRAIGHT: 2,
    Command.LANE_FOLLOW: 3,
    Command.CHANGE_LANE_LEFT: 4,
    Command.CHANGE_LANE_RIGHT: 5,
    Command.UNKNOWN: 3,
}
#: WOD-E2E's intent enum order (UNKNOWN, GO_STRAIGHT, GO_LEFT, GO_RIGHT), as LEAD's WOD loader one-hots it.
WOD_COMMAND_INDEX = {Command.UNKNOWN: 0, Command.STRAIGHT: 1, Command.LEFT: 2, Command.RIGHT: 3}
#: LEAD's CenterNet fields -> our box head's names (``lead_s2r.training.losses.box_loss``).
BOX_FIELDS = {
    "center_heatmap_logit_pred": "box_heatmap",
    "offset_pred": "box_offset",
    "wh_pred": "box_size",
    "yaw_class_pred": "box_yaw_class",
    "yaw_res_pred": "box_yaw_residual",
    "velocity_pred": "box_velocity",
}
#: LEAD's outputs that only get our names, and those whose lateral coordinate also changes sign.
RENAMED = {"pred_semantic": "semantic", "pred_depth": "depth", "pred_target_speed_distribution": "target_speed_logits"}
FLIPPED = {"pred_future_waypoints": "waypoints", "pred_route": "route"}
#: LEAD's radar rows per sensor (``num_radar_points_per_sensor``).
RADAR_ROWS_PER_SENSOR = 75
#: Slots of our ``target_points`` (B, 3, 2): previous, current, next.
TARGET_POINT_KEYS = ("target_point_previous", "target_point", "target_point_next")


def flip_y(points: Tensor) -> Tensor:
    """(..., >= 2) points with the lateral coordinate negated (column 1); other columns unchanged."""
    flipped = points.clone()
    flipped[..., 1] = -flipped[..., 1]
    return flipped


def lidar_to_lead(lidar_bev: Tensor) -> Tensor:
    """Our (B, C, H=x, W=y left) raster -> LEAD's (B, C, rows = y from left to right, columns = x), in [0, 1]."""
    return lidar_input(lidar_bev, torch.float32).transpose(-1, -2).flip(-2)


def bev_map_from_lead(lead_map: Tensor) -> Tensor:
    """LEAD's (B, C, rows = y left to right, columns = x) map -> ours (B, C, H=x, W=y left); inverse of the raster's."""
    return lead_map.flip(-2).transpose(-1, -2)


def command_one_hot(command: Tensor, config: LeadConfig, full: Tensor | None = None) -> Tensor:
    """(B,) our 4-way command ids -> (B, discrete_command_dim) LEAD one-hot; in CARLA leaderboard mode the 7-way
    ``full`` command (``command_full``), where the batch has it, gives LEAD's 6 CARLA commands."""
    command = full if config.carla_leaderboard_mode and full is not None else command
    table = CARLA_FULL_COMMAND_INDEX if config.carla_leaderboard_mode else NAVSIM_COMMAND_INDEX
    table = WOD_COMMAND_INDEX if config.is_wod else table
    lookup = torch.tensor([table.get(ours, 0) for ours in Command], device=command.device)
    index = lookup[command.long()]
    return torch.nn.functional.one_hot(index, config.discrete_command_dim).float()


def radar_to_lead(radar: Tensor, valid: Tensor, config: LeadConfig) -> Tensor:
    """Our (B, N, 5) radar rows (ISO) with their mask -> LEAD's sensor-major (B, sensors x 75, 5), y flipped."""
    flipped = flip_y(radar.float())
    (x0, x1), (y0, y1) = config.bev_extent
    x, y = flipped[..., 0], flipped[..., 1]
    inside = valid & (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    sensors, rows = config.num_radar_sensors, RADAR_ROWS_PER_SENSOR
    out = torch.zeros(len(radar), sensors * rows, 5, device=radar.device)
    out[..., 4] = torch.arange(sensors, device=radar.device).repeat_interleave(rows).float()
    for b in range(len(radar)):
        for sensor in range(sensors):
            points = flipped[b][inside[b] & (flipped[b, :, 4] == sensor)][:rows]
            out[b, sensor * rows : sensor * rows + len(points)] = points
    return out


def to_lead_inputs(batch: Batch, config: LeadConfig) -> dict[str, Tensor]:
    """Our batch -> LEAD's input dict (keys, units and frame of LEAD's ``TFv6.forward``)."""
    speed = batch["speed"].float()
    command = command_one_hot(batch["command"], config, batch.get("command_full"))
    out: dict[str, Tensor] = {"rgb": batch["rgb"], "speed": speed, "command": command}
    accel = batch.get("acceleration")
    out["acceleration"] = accel.float().reshape(len(speed), -1).norm(dim=-1) if accel is not None else speed * 0
    if "lidar_bev" in batch:
        out["rasterized_lidar"] = lidar_to_lead(batch["lidar_bev"])
    if "target_points" in batch:
        points = flip_y(batch["target_points"].float())
        out.update({key: points[:, i] for i, key in enumerate(TARGET_POINT_KEYS)})
    if "radar" in batch:
        valid = batch.get("radar_valid", torch.ones(batch["radar"].shape[:2], dtype=torch.bool))
        out["radar"] = radar_to_lead(batch["radar"], valid.to(batch["radar"].device), config)
    return out


def boxes_from_lead(maps: dict[str, Tensor]) -> dict[str, Tensor]:
    """LEAD's CenterNet maps (``BOX_FIELDS`` keys) -> our box names on our grid, in our frame: LEAD's lateral offset is
    a cell's fraction from its other edge and its yaw turns the other way; sizes, speed and heatmaps only move."""
    ours = {BOX_FIELDS[field]: bev_map_from_lead(value) for field, value in maps.items() if field in BOX_FIELDS}
    if "box_offset" in ours:
        offset = ours["box_offset"]
        ours["box_offset"] = torch.cat([offset[:, :1], 1 - offset[:, 1:]], dim=1)
    if "box_yaw_class" in ours:
        bins = ours["box_yaw_class"].shape[1]
        ours["box_yaw_class"] = ours["box_yaw_class"][:, [(-k) % bins for k in range(bins)]]
    if "box_yaw_residual" in ours:
        ours["box_yaw_residual"] = -ours["box_yaw_residual"]
    return ours


def from_lead_outputs(outputs: dict[str, Tensor], source: str) -> dict[str, Tensor]:
    """LEAD's outputs -> our names in the ISO frame; BEV maps of ``source``'s heads (NAVSIM's or LEAD's CARLA ones)."""
    suffix = "_navsim" if source == "navsim" else ""
    ours: dict[str, Tensor] = {}
    if f"pred_bev_semantic{suffix}" in outputs:
        ours["bev_semantic"] = bev_map_from_lead(outputs[f"pred_bev_semantic{suffix}"])
    prefix = f"pred_bounding_box{suffix}."
    ours.update(boxes_from_lead({k[len(prefix) :]: v for k, v in outputs.items() if k.startswith(prefix)}))
    ours.update({name: outputs[key] for key, name in RENAMED.items() if key in outputs})
    ours.update({name: flip_y(outputs[key]) for key, name in FLIPPED.items() if key in outputs})
    if "pred_headings" in outputs:
        ours["headings"] = -outputs["pred_headings"]
    if "pred_radar_predictions" in outputs:
        radar = outputs["pred_radar_predictions"]  # x, y (m, LEAD's frame), v (m/s), validity logit
        ours.update(radar_xy=flip_y(radar[..., :2]), radar_speed=radar[..., 2], radar_logit=radar[..., 3])
    return ours
