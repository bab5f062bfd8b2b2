"""Camera images of the synthetic NAVSIM world: what a camera-only planner (LTFv6) needs to see to learn to drive.

Noise images leave a planner the ego status alone, so it cannot see the lead car it follows nor the junction it
turns at. Each image here is rendered through the camera's own calibration (intrinsics, the distortion written
beside it, its pose on the ego): sky above the horizon and beyond :data:`FAR`; on the ground plane the roads, car
park, walkway and grass of :mod:`navsim_map` with the side lines of its lanes (none inside the junction, as on real
roads); and every annotated box as a filled silhouette of its 8 projected corners, far ones first. A pixel's ground
point comes from its undistorted ray (OpenCV ``undistortPoints``), computed once per camera; a frame only moves
those points into the map frame and reads their colour off a raster of the map painted once per process (OpenCV
``remap``), so an image costs about what a noise image did.
"""

from dataclasses import dataclass
from functools import cached_property, lru_cache

import cv2
import numpy as np

from lead_s2r.geometry import box_corners
from lead_s2r.synthetic import navsim_map, pedestrians_ahead

#: BGR colours.
SKY, GRASS, MARKING = (205, 170, 130), (70, 115, 80), (235, 235, 235)
#: Map areas in painting order (a later one covers an earlier one where they touch) and their colours.
AREAS = (
    ((*navsim_map.CARPARKS.values(),), (125, 125, 130)),
    ((*navsim_map.WALKWAYS.values(),), (175, 175, 170)),
    ((*navsim_map.ROADBLOCKS.values(), *navsim_map.INTERSECTIONS.values()), (85, 85, 90)),
)
BOX_COLOURS = {"vehicle": (40, 40, 170), "pedestrian": pedestrians_ahead.COLOUR, "bicycle": (200, 60, 200)}
OTHER_BOX = (20, 120, 240)
MARKING_HALF_WIDTH = 0.1
#: Cell size of the map raster (m).
RESOLUTION = 0.05
#: Ground farther than this (m) is drawn as sky, as a real camera's far field washes out.
FAR = 80.0
#: Pixel noise: uniform in [-NOISE, NOISE] grey levels (every colour above is at least NOISE from 0 and 255).
NOISE = 4


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera with radial-tangential distortion: intrinsics ``K``, OpenCV ``distortion`` (k1 k2 p1 p2 k3),
    rotation optical -> ego and optical centre in the ego frame; ``size`` (width, height)."""

    K: np.ndarray
    distortion: np.ndarray
    rotation: np.ndarray
    origin: np.ndarray
    size: tuple[int, int]

    @cached_property
    def ground(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per pixel: where its ray meets the ground (z = 0) in the ego frame, x and y (H, W) float32 each, and the
        flat indices of the pixels that miss the ground within :data:`FAR` metres, looking at the sky."""
        width, height = self.size
        u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
        pixels = np.stack([u, v], axis=-1).reshape(-1, 1, 2).astype(np.float64)
        normalised = cv2.undistortPoints(pixels, self.K, self.distortion).reshape(-1, 2)
        rays = np.column_stack([normalised, np.ones(len(normalised))]) @ self.rotation.T
        down = rays[:, 2] < -1e-6
        depth = np.where(down, -self.origin[2] / np.where(down, rays[:, 2], -1.0), 0.0)
        points = self.origin[:2] + depth[:, None] * rays[:, :2]
        sky = ~down | (np.linalg.norm(points - self.origin[:2], axis=1) >= FAR)
        x, y = points.astype(np.float32).reshape(height, width, 2).transpose(2, 0, 1)
        return x, y, np.flatnonzero(sky)

    def project(self, points: np.ndarray) -> np.ndarray | None:
        """Ego-frame points (N, 3) -> pixels (N, 2), or None when any lies behind the camera."""
        optical = (points - self.origin) @ self.rotation
        if (optical[:, 2] < 0.3).any():
            return None
        pixels, _ = cv2.projectPoints(optical, np.zeros(3), np.zeros(3), self.K, self.distortion)
        return pixels.reshape(-1, 2)


def marking_boxes() -> list[tuple[float, float, float, float]]:
    """The side lines of every straight lane as thin boxes (x0, y0, x1, y1); the lanes run along x or y."""
    boxes = []
    for lane in navsim_map.LANES:
        (x0, y0), (x1, y1) = lane.centerline[0], lane.centerline[-1]
        if x0 != x1 and y0 != y1:
            raise ValueError(f"lane {lane.fid} runs along neither axis; the camera renderer paints only such lanes")
        across = np.array([y0 != y1, x0 != x1], np.float64)
        for side in (-navsim_map.HALF_LANE, navsim_map.HALF_LANE):
            ends = np.array([[x0, y0], [x1, y1]]) + side * across
            boxes.append((*(ends.min(axis=0) - MARKING_HALF_WIDTH), *(ends.max(axis=0) + MARKING_HALF_WIDTH)))
    return boxes


@lru_cache(maxsize=1)
def map_colours() -> tuple[np.ndarray, np.ndarray]:
    """The map painted as a BGR raster (rows along y, columns along x, :data:`RESOLUTION` cells from the map's
    lower-left corner) and that corner."""
    corner = np.min([box[:2] for areas, _ in AREAS for box in areas], axis=0)
    far = np.max([box[2:] for areas, _ in AREAS for box in areas], axis=0)
    columns, rows = np.ceil((far - corner) / RESOLUTION).astype(np.int64)
    raster = np.full((rows, columns, 3), GRASS, np.uint8)
    for areas, colour in [*AREAS, (marking_boxes(), MARKING)]:
        for box in areas:
            (c0, r0), (c1, r1) = np.round((np.reshape(box, (2, 2)) - corner) / RESOLUTION).astype(np.int64)
            raster[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = colour
    return raster, corner


def box_corners_3d(box: np.ndarray) -> np.ndarray:
    """(8, 3) corners of an OpenScene box [x, y, z (centre), length, width, height, yaw]: its footprint
    (:func:`~lead_s2r.geometry.box_corners`) at the bottom and at the top."""
    footprint = box_corners(box[None])[0]
    heights = box[2] + box[5] / 2 * np.array([-1.0, 1.0])
    return np.concatenate([np.column_stack([footprint, np.full(4, z)]) for z in heights])


def render(
    camera: Camera, pose: np.ndarray, boxes: np.ndarray, names: list[str], rng: np.random.Generator
) -> np.ndarray:
    """The (H, W, 3) uint8 BGR image of ``camera`` on an ego at the local map pose ``pose`` [x, y, yaw], with the
    annotated ``boxes`` (N, 7, ego frame) of classes ``names``."""
    x, y, sky = camera.ground
    raster, corner = map_colours()
    cos, sin = np.float32(np.cos(pose[2]) / RESOLUTION), np.float32(np.sin(pose[2]) / RESOLUTION)
    column, row = (pose[:2] - corner) / RESOLUTION - 0.5
    columns, rows = x * cos - y * sin + np.float32(column), x * sin + y * cos + np.float32(row)
    image = cv2.remap(raster, columns, rows, cv2.INTER_NEAREST, borderValue=GRASS)
    width, height = camera.size
    image.reshape(-1, 3)[sky] = SKY
    for i in np.argsort(-np.hypot(boxes[:, 0], boxes[:, 1])):
        pixels = camera.project(box_corners_3d(boxes[i]))
        if pixels is not None and np.isfinite(pixels).all() and np.abs(pixels).max() < 10 * width:
            hull = cv2.convexHull(np.round(pixels).astype(np.int32))
            cv2.fillConvexPoly(image, hull, BOX_COLOURS.get(names[i], OTHER_BOX))
    image += rng.integers(0, 2 * NOISE + 1, (height, width, 1), dtype=np.uint8)
    image -= NOISE
    return image
