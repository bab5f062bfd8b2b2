"""LEAD's CARLA frame has its origin at the vehicle centre, ours at the rear axle: a LEAD network reading CARLA data
gets every geometric input and label moved to the centre, as LEAD's CARLA loader gives them.

Our adapters put the origin at the rear axle (docs/conventions.md); LEAD's CARLA loader keeps the expert's frame, whose
origin is the vehicle centre (``rear_axle_to_center`` = 1.389 m ahead for LEAD's car), while its NAVSIM loader keeps
NAVSIM's rear axle. A LEAD CARLA network fed rear-axle geometry sees its LiDAR raster, BEV labels and CenterNet targets
5.6 pixels (at 4 px/m) off where it was trained to see them, and its target points 1.389 m too far ahead. The axes
stay ours (y left); :mod:`lead_s2r.models.lead_frame` flips y at the network's boundary.

Points (LiDAR, radar, target points, route, box centres) shift along x; the future's poses become the centre's poses
(each pose's own origin moves forward along its heading); the stored BEV raster's pixel-to-ego affine shifts, so its
lookup lands on the same pixels LEAD crops. The batch keeps the shift (``origin_x``), and predicted waypoints of such
a network, centre positions in the centre frame, go back to rear-axle positions in our frame through
:func:`centre_waypoints_to_rear_axle`.
"""

from collections.abc import Collection
from typing import Any

import numpy as np
import torch
from torch import Tensor

from lead_s2r.geometry import rear_axle_poses_to_centre

#: Metres a predicted step must move for its direction to count as the heading there (below: the heading so far).
MIN_STEP_M = 0.1
#: Rounds of :func:`centre_waypoints_to_rear_axle`'s heading estimate.
FIXED_POINT_ROUNDS = 4
#: Fields whose rows are points with x in column 0.
POINT_FIELDS = ("lidar", "radar", "target_points", "route", "boxes")


def centre_shift(sample: dict[str, Any]) -> float:
    """Metres from the rear axle forward to the vehicle centre (``meta.vehicle.rear_axle_to_center``)."""
    return float(sample["meta"]["vehicle"]["rear_axle_to_center"])


def to_centre_origin(sample: dict[str, Any], keep: Collection[str] = ()) -> dict[str, Any]:
    """``sample`` (a shallow copy) with its geometry in the vehicle-centre frame: x - :func:`centre_shift`.

    Point fields in ``keep`` stay in the rear-axle frame for a caller that moves them as it reads them: the LiDAR
    cloud (60,000 points) is shifted inside its raster (:func:`~lead_s2r.data.lidar.rasterize_lidar`'s ``x_shift``,
    the same float32 subtraction), not copied here first."""
    shift = centre_shift(sample)
    moved = dict(sample)
    for name in POINT_FIELDS:
        if name in sample and name not in keep:
            points = np.array(sample[name], copy=True)
            points[:, 0] -= points.dtype.type(shift)
            moved[name] = points
    if "future" in sample:
        future = np.array(sample["future"], np.float64, copy=True)
        future[:, 1:] = rear_axle_poses_to_centre(future[:, 1:], shift)
        moved["future"] = future.astype(np.float32)
    bev = sample["meta"].get("bev")
    if bev is not None:
        affine = np.array(bev["pixel_to_ego"], np.float64)
        affine[0, 2] -= shift
        moved["meta"] = {**sample["meta"], "bev": {**bev, "pixel_to_ego": affine.tolist()}}
    return moved


def centre_waypoints_to_rear_axle(xy: Tensor, origin_x: Tensor) -> Tensor:
    """(B, T, 2) predicted vehicle-centre positions in the centre frame -> rear-axle positions in the rear-axle frame,
    for samples whose origin moved ``origin_x`` (B,) metres forward (0: left as they are).

    LEAD's CARLA planner predicts no headings it was trained on, so the headings come from the path: a rear axle moves
    along its heading, so each waypoint's heading is the direction of the rear-axle path through it (from the point
    before to the one after; the last one turning on as the one before it did), found by a few fixed-point rounds
    starting from the centre's path, and kept from before where the path stands still (chord under :data:`MIN_STEP_M`).
    On a 10 m radius turn at 6 m/s this lands within 2 cm of the true rear axle (tests/test_lead_data_parity.py)."""
    shift = origin_x.to(xy.dtype)[:, None]
    rear = xy.clone()
    for _ in range(FIXED_POINT_ROUNDS):
        heading = _path_headings(rear)
        rear = torch.stack([xy[..., 0] + shift * (1 - torch.cos(heading)), xy[..., 1] - shift * torch.sin(heading)], -1)
    return rear


def _path_headings(path: Tensor) -> Tensor:
    """(B, T) direction of the (B, T, 2) path through each point, starting from the origin (see above)."""
    padded = torch.cat([torch.zeros_like(path[:, :1]), path], dim=1)
    chords = padded[:, 2:] - padded[:, :-2]
    heading, headings = torch.zeros_like(path[:, 0, 0]), []
    for t in range(path.shape[1] - 1):
        moving = chords[:, t].norm(dim=-1) >= MIN_STEP_M
        heading = torch.where(moving, torch.atan2(chords[:, t, 1], chords[:, t, 0]), heading)
        headings.append(heading)
    turn = headings[-1] - headings[-2] if len(headings) > 1 else torch.zeros_like(heading)
    headings.append(heading + torch.remainder(turn + torch.pi, 2 * torch.pi) - torch.pi)  # the last: turning on
    return torch.stack(headings, dim=1)
