"""LEAD's CARLA frame has its origin at the vehicle centre, ours at the rear axle: a LEAD network reading CARLA data
gets every geometric input and label moved to the centre, as LEAD's CARLA loader gives them.

Our adapters put the origin at the rear axle (docs/conventions.md); LEAD's CARLA loader keeps the expert's frame, whose
origin is the vehicle centre (``rear_axle_to_center`` = 1.389 m ahead for LEAD's car), while its NAVSIM loader keeps
NAVSIM's rear axle. A LEAD CARLA network fed rear-axle geometry sees its LiDAR raster, BEV labels and CenterNet targets
5.6 pixels (at 4 px/m) off where it was trained to see them, and its target points 1.389 m too far ahead. The axes
stay ours (y left); :mod:`lead_s2r.models.lead_frame` flips y at the network's boundary.

Points (LiDAR, radar, target points, route, box centres) shift along x; the future's poses become the centre's poses
(each pose's own origin moves forward along its heading); the stored BEV raster's pixel-to-ego affine shifts, so its
lookup lands on the same pixels LEAD crops. Predicted waypoints of such a network are centre positions in the centre
frame: :func:`centre_waypoints_to_rear_axle` turns them back.
"""

from typing import Any

import numpy as np

from lead_s2r.geometry import rear_axle_poses_to_centre

#: Fields whose rows are points with x in column 0.
POINT_FIELDS = ("lidar", "radar", "target_points", "route", "boxes")


def to_centre_origin(sample: dict[str, Any]) -> dict[str, Any]:
    """``sample`` (a shallow copy) with its geometry in the vehicle-centre frame: x - ``rear_axle_to_center``."""
    shift = float(sample["meta"]["vehicle"]["rear_axle_to_center"])
    moved = dict(sample)
    for name in POINT_FIELDS:
        if name in sample:
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
