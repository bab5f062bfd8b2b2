"""Trajectories drawn into a sample's forward camera(s) through the stored calibration.

``cam_to_ego`` maps OpenCV camera axes (x right, y down, z forward) to the ISO ego frame (docs/conventions.md), so
a ground point of the ego frame goes to the camera by the inverse transform and to the pixel by OpenCV's pinhole +
Brown-Conrady model (``cv2.projectPoints``, the same five coefficients the adapters store). Trajectory points lie on
the ground (z = 0 at the rear axle). Points less than :data:`NEAR_M` in front of the lens are dropped: behind the
camera a pinhole projection flips the picture over. So are points beyond the radius where the distortion polynomial
stops growing (:func:`monotonic_radius`): far outside the field of view it folds back and would put a point that
the camera cannot see inside its picture.
"""

from typing import Any

import cv2
import numpy as np
from matplotlib.figure import Figure

from lead_s2r.report.bev import save_figure, trajectory_colors

NEAR_M = 0.5
#: the largest normalised radius (tan of the angle off the optical axis) searched for the distortion's fold
MAX_RADIUS = 10.0
#: a camera counts as forward when its optical axis is within 60 degrees of the ego's x axis
FORWARD_COSINE = 0.5


def monotonic_radius(distortion: np.ndarray) -> float:
    """The normalised radius up to which Brown-Conrady's radial term ``r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` grows
    (inf when it always does): the part of the model that is a projection."""
    k1, k2, k3 = (float(distortion[i]) if len(distortion) > i else 0.0 for i in (0, 1, 4))
    r = np.linspace(0.0, MAX_RADIUS, 4001)
    slope = 1 + 3 * k1 * r**2 + 5 * k2 * r**4 + 7 * k3 * r**6
    falling = np.flatnonzero(slope <= 0)
    return float(r[falling[0]]) if len(falling) else np.inf


def project_points(camera: dict[str, Any], points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ego-frame points ``(N, 3)`` -> pixels ``(N, 2)`` of ``camera`` (a ``meta.cameras`` entry; a mosaic tile's
    pixels are in the stored mosaic) and a mask of those in front of the lens and inside the picture."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    ego_to_cam = np.linalg.inv(np.asarray(camera["cam_to_ego"], np.float64))
    optical = points @ ego_to_cam[:3, :3].T + ego_to_cam[:3, 3]
    distortion = np.asarray(camera["distortion"], np.float64)
    in_front = optical[:, 2] > NEAR_M
    radius = np.hypot(optical[:, 0], optical[:, 1]) / np.where(in_front, optical[:, 2], 1.0)
    in_front &= radius < monotonic_radius(distortion)
    pixels = np.full((len(points), 2), np.nan)
    if in_front.any():
        K = np.asarray(camera["K"], np.float64)
        projected, _ = cv2.projectPoints(optical[in_front], np.zeros(3), np.zeros(3), K, distortion)
        pixels[in_front] = projected.reshape(-1, 2)
    x0, width = camera.get("tile", (0, camera["width"]))
    pixels[:, 0] += x0
    inside = in_front & (pixels[:, 0] >= x0) & (pixels[:, 0] < x0 + width)
    inside &= (pixels[:, 1] >= 0) & (pixels[:, 1] < camera["height"])
    return pixels, inside


def on_ground(xy: np.ndarray) -> np.ndarray:
    """Ego-frame ``(N, 2)`` positions as ground points ``(N, 3)``."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    return np.column_stack([xy, np.zeros(len(xy))])


def forward_cameras(sample: dict[str, Any]) -> list[dict[str, Any]]:
    """The cameras (or mosaic tiles) of the sample that look forward and whose image is stored."""
    return [
        camera
        for camera in sample["meta"].get("cameras", [])
        if f"cam_{camera['id']}" in sample and np.asarray(camera["cam_to_ego"], np.float64)[0, 2] > FORWARD_COSINE
    ]


def decode(sample: dict[str, Any], field: str) -> np.ndarray | None:
    """A stored camera image (``cam_<id>``) as RGB (None when it does not decode)."""
    image = cv2.imdecode(np.frombuffer(sample[field], np.uint8), cv2.IMREAD_COLOR)
    return None if image is None else cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def camera_figure(
    sample: dict[str, Any], camera: dict[str, Any], trajectories: dict[str, np.ndarray], out: Any
) -> bool:
    """Draw ``{label: (T, 2) ego-frame xy}`` into the camera's image and save it to ``out``; False when the image
    does not decode. Colours are the BEV's (:func:`~lead_s2r.report.bev.trajectory_colors`)."""
    image = decode(sample, f"cam_{camera['id']}")
    if image is None:
        return False
    x0, width = camera.get("tile", (0, image.shape[1]))
    image = image[:, x0 : x0 + width]
    height = image.shape[0]
    figure = Figure(figsize=(6.0, 6.0 * height / width), dpi=100)
    axes = figure.add_axes((0, 0, 1, 1))
    axes.imshow(image, extent=(x0, x0 + width, height, 0))
    colors = trajectory_colors(list(trajectories))
    for label, xy in trajectories.items():
        pixels, inside = project_points(camera, on_ground(xy))
        axes.plot(pixels[inside, 0], pixels[inside, 1], "o-", color=colors[label], markersize=3, label=label)
    axes.set_xlim(x0, x0 + width)
    axes.set_ylim(height, 0)
    axes.set_axis_off()
    if trajectories:
        axes.legend(loc="upper right", fontsize=7)
    save_figure(figure, out)
    return True
