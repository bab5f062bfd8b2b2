"""Camera images of the synthetic WOD-E2E world: sky above the horizon, road below, and the pedestrians standing in
the lane ahead (:mod:`lead_s2r.synthetic.pedestrians_ahead`) as filled rectangles, so a camera model can see what
the ego status cannot. A pinhole projection through the written intrinsics and extrinsics (Waymo camera axes: x
along the optical axis, y left, z up); the images are a few dozen pixels wide, where lens distortion is invisible.
"""

import cv2
import numpy as np

from lead_s2r.synthetic import pedestrians_ahead

SKY, ROAD = (205, 170, 130), (85, 85, 90)
#: Pixel noise: uniform in [-NOISE, NOISE] grey levels.
NOISE = 4
#: Points closer than this along the optical axis (m) are not drawn.
NEAR = 0.5
#: The pedestrians are drawn this many times their size, across and up, about the row's centre: a real front camera
#: shows the row 60-270 pixels across, these cameras at 1/18 of its size 3-15, which the quickstart's LTFv6 twins do
#: not learn to see in a few hundred steps; three times larger, they read their cameras (docs/training.md, "Toy
#: cameras: the pedestrians drawn larger"). Only the pixels change: the positions, the driving and the labels are the
#: world's.
DRAWN_SCALE = 3.0


def project(points: np.ndarray, intrinsic: list[float], extrinsic: list[float]) -> np.ndarray:
    """Vehicle-frame points (N, 3) -> pixels (N, 2) and depth along the optical axis (N,), as (N, 3)."""
    matrix = np.asarray(extrinsic, np.float64).reshape(4, 4)
    camera = (points - matrix[:3, 3]) @ matrix[:3, :3]  # camera -> vehicle is R, t: camera = R^T (p - t)
    f_u, f_v, c_u, c_v = intrinsic[:4]
    depth = camera[:, 0]
    safe = np.where(depth > NEAR, depth, 1.0)
    return np.column_stack([c_u - f_u * camera[:, 1] / safe, c_v - f_v * camera[:, 2] / safe, depth])


def render(
    size: tuple[int, int],
    intrinsic: list[float],
    extrinsic: list[float],
    pedestrians: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """(height, width, 3) uint8 BGR image of a camera of ``size``, with ``pedestrians`` (N, 2) ground positions in the
    vehicle frame (one row), far ones first, drawn :data:`DRAWN_SCALE` times their size."""
    height, width = size
    image = np.full((height, width, 3), ROAD, np.uint8)
    image[: round(intrinsic[3])] = SKY  # above the horizon
    half, tall = DRAWN_SCALE * pedestrians_ahead.SIZE[1] / 2, DRAWN_SCALE * pedestrians_ahead.SIZE[2]
    centre = pedestrians.mean(axis=0) if len(pedestrians) else np.zeros(2)
    for x, y in sorted(centre + DRAWN_SCALE * (pedestrians - centre), key=lambda p: -np.hypot(*p)):
        corners = np.array([[x, y + half, 0.0], [x, y - half, 0.0], [x, y + half, tall], [x, y - half, tall]])
        pixels = project(corners, intrinsic, extrinsic)
        if (pixels[:, 2] <= NEAR).any():
            continue
        (u0, v0), (u1, v1) = pixels[:, :2].min(axis=0), pixels[:, :2].max(axis=0)
        if u1 < 0 or u0 >= width:
            continue
        top_left = (int(np.floor(u0)), int(np.floor(v0)))
        bottom_right = (int(np.ceil(u1)), int(np.ceil(v1)))
        cv2.rectangle(image, top_left, bottom_right, pedestrians_ahead.COLOUR, thickness=-1)
    image += rng.integers(0, 2 * NOISE + 1, (height, width, 1), dtype=np.uint8)
    image -= NOISE
    return image
