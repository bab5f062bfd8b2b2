"""Draw one sample as a picture a person can check at a glance: cameras on top, a BEV of the ego frame below.

BEV: x forward points up, y left points left (ISO 8855 seen from above), ego rear axle marked; past grey,
future green, boxes orange, target points red, route blue, LiDAR points faint, BEV semantic classes as muted
colours underneath.
"""

from typing import Any

import cv2
import numpy as np

from lead_s2r.geometry import box_corners, raster_lookup

CANVAS_WIDTH = 960
BEV_RANGE_M = (-16.0, 48.0, -32.0, 32.0)  # x min, x max, y min, y max
BEV_PX_PER_M = 10


def _bev_pixels(xy: np.ndarray) -> np.ndarray:
    """Ego-frame metres (N, 2) -> BEV pixel (col, row): forward is up, left is left."""
    x_max, y_max = BEV_RANGE_M[1], BEV_RANGE_M[3]
    cols = (y_max - xy[:, 1]) * BEV_PX_PER_M
    rows = (x_max - xy[:, 0]) * BEV_PX_PER_M
    return np.stack([cols, rows], axis=1)


def _polyline(image: np.ndarray, xy: np.ndarray, color: tuple[int, int, int], radius: int) -> None:
    xy = xy[np.isfinite(xy).all(axis=1)]
    if len(xy) == 0:
        return
    pixels = np.round(_bev_pixels(xy)).astype(np.int32)
    cv2.polylines(image, [pixels.reshape(-1, 1, 2)], False, color, 2, cv2.LINE_AA)
    for col, row in pixels:
        cv2.circle(image, (int(col), int(row)), radius, color, -1, cv2.LINE_AA)


def _semantic_layer(sample: dict[str, Any], height: int, width: int) -> np.ndarray | None:
    """The stored BEV semantic raster resampled onto the panel, one muted colour per class (BGR)."""
    spec = sample["meta"].get("bev")
    if "bev_semantic" not in sample or not spec or "pixel_to_ego" not in spec:
        return None
    x_max, y_max = BEV_RANGE_M[1], BEV_RANGE_M[3]
    rows, cols = np.mgrid[0:height, 0:width]
    x, y = x_max - (rows + 0.5) / BEV_PX_PER_M, y_max - (cols + 0.5) / BEV_PX_PER_M
    labels = raster_lookup(sample["bev_semantic"], spec["pixel_to_ego"], x, y, fill=0)
    palette = cv2.applyColorMap(np.linspace(0, 255, 16, dtype=np.uint8)[:, None], cv2.COLORMAP_TURBO)[:, 0]
    palette = (palette.astype(np.float32) * 0.45).astype(np.uint8)
    palette[0] = 30  # class 0 (unlabeled / background) stays the canvas colour
    return palette[np.clip(labels, 0, 15)]


def render_bev(sample: dict[str, Any]) -> np.ndarray:
    """The BEV panel of one sample as a BGR image."""
    x_min, x_max, y_min, y_max = BEV_RANGE_M
    height, width = int((x_max - x_min) * BEV_PX_PER_M), int((y_max - y_min) * BEV_PX_PER_M)
    semantic = _semantic_layer(sample, height, width)
    image = np.full((height, width, 3), 30, np.uint8) if semantic is None else semantic
    for metres in range(int(x_min), int(x_max) + 1, 8):  # grid every 8 m
        row = int((x_max - metres) * BEV_PX_PER_M)
        cv2.line(image, (0, row), (width, row), (55, 55, 55), 1)
    if "lidar" in sample:
        pixels = np.round(_bev_pixels(sample["lidar"][:, :2])).astype(np.int64)
        inside = (pixels[:, 0] >= 0) & (pixels[:, 0] < width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < height)
        image[pixels[inside, 1], pixels[inside, 0]] = (110, 110, 110)
    if "route" in sample:
        _polyline(image, sample["route"], (230, 150, 40), 1)
    for corners in box_corners(sample.get("boxes", np.zeros((0, 10)))):
        pixels = np.round(_bev_pixels(corners)).astype(np.int32)
        cv2.polylines(image, [pixels.reshape(-1, 1, 2)], True, (0, 150, 255), 2, cv2.LINE_AA)
    _polyline(image, sample["past"][:, 1:3], (160, 160, 160), 2)
    if "future" in sample:
        _polyline(image, sample["future"][:, 1:3], (60, 220, 60), 2)
    if "target_points" in sample:
        for point in sample["target_points"]:
            if np.isfinite(point).all():
                col, row = np.round(_bev_pixels(point[None]))[0].astype(int)
                cv2.circle(image, (col, row), 6, (40, 40, 240), -1, cv2.LINE_AA)
    vehicle = sample["meta"]["vehicle"]
    ego = np.array([vehicle["rear_axle_to_center"], 0, 0, vehicle["length"], vehicle["width"], 0, 0], np.float64)
    corners = np.round(_bev_pixels(box_corners(ego[None])[0])).astype(np.int32)
    cv2.fillPoly(image, [corners.reshape(-1, 1, 2)], (255, 255, 255))
    return image


def _camera_strip(sample: dict[str, Any], width: int) -> np.ndarray | None:
    names = sorted(name for name in sample if name.startswith("cam_"))
    images = [cv2.imdecode(np.frombuffer(sample[name], np.uint8), cv2.IMREAD_COLOR) for name in names]
    images = [image for image in images if image is not None]
    if not images:
        return None
    tile_width = width // len(images)
    tiles = [cv2.resize(image, (tile_width, max(1, image.shape[0] * tile_width // image.shape[1]))) for image in images]
    tile_height = max(tile.shape[0] for tile in tiles)
    tiles = [cv2.copyMakeBorder(t, 0, tile_height - t.shape[0], 0, 0, cv2.BORDER_CONSTANT) for t in tiles]
    strip = np.hstack(tiles)
    return cv2.copyMakeBorder(strip, 0, 0, 0, width - strip.shape[1], cv2.BORDER_CONSTANT)


#: characters of the sample key per line of the legend (keys run to 70 characters: NAVSIM log name + token)
KEY_CHARS_PER_LINE = 40


def render_sample(sample: dict[str, Any]) -> np.ndarray:
    """Cameras above the BEV, with the sample key and ego state written in the corner (BGR image)."""
    bev = render_bev(sample)
    bev = cv2.copyMakeBorder(bev, 0, 0, 0, CANVAS_WIDTH - bev.shape[1], cv2.BORDER_CONSTANT, value=(20, 20, 20))
    ego = sample["meta"]["ego"]
    key = sample["__key__"]
    lines = [
        *(key[i : i + KEY_CHARS_PER_LINE] for i in range(0, len(key), KEY_CHARS_PER_LINE)),  # whole, over lines
        f"speed {ego['speed']:.2f} m/s",
        f"command {ego['command']} (raw {ego['command_raw']})",
        "",
        "x forward = up, y left = left",
        "past grey, future green",
        "boxes orange, target points red",
        "route blue, lidar dots, grid 8 m",
        "BEV semantic classes underneath",
    ]
    for i, line in enumerate(lines):
        cv2.putText(bev, line, (650, 30 + 22 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (230, 230, 230), 1, cv2.LINE_AA)
    cameras = _camera_strip(sample, CANVAS_WIDTH)
    return bev if cameras is None else np.vstack([cameras, bev])
