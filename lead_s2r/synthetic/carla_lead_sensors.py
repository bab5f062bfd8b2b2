"""The sensor files of the synthetic LEAD routes (:mod:`lead_s2r.synthetic.carla_lead`): camera mosaic, semantics,
depth, hdmap raster, LiDAR (light and realistic), the LAZ writer and radar, each as LEAD's expert writes them."""

from pathlib import Path

import cv2
import numpy as np

from lead_s2r.geometry import points_to_local, rotate
from lead_s2r.synthetic import pedestrians_ahead

#: CARLA's simulation rate, Hz (LiDAR sweeps come at this rate).
FPS = 20

#: Camera rig (LEAD's ``TargetDataset`` name) -> (tiles, tile width, stored rows) of the stitched JPEG.
RIG_MOSAICS = {
    "CARLA_LEADERBOARD2_3CAMERAS": (3, 384, 384),
    "CARLA_LEADERBOARD2_6CAMERAS": (6, 384, 384),
    "CARLA_PY123D_1CAMERA": (1, 1024, 384),
    "NAVSIM_4CAMERAS": (4, 480, 270),
}
DEPTH_RATIO = 4
HDMAP_SIZE = 256
HDMAP_PX_PER_M = 2.0


def mosaic_shape(rig: str) -> tuple[int, int]:
    """(height, width) of a rig's stored mosaic."""
    tiles, width, height = RIG_MOSAICS[rig]
    return height, tiles * width


#: The front camera of the mosaic (its middle tile): horizontal field of view (deg) and height above the ground (m).
FRONT_FOV, CAMERA_HEIGHT = 60.0, 2.0


def mosaic(rig: str, frame: int, shift: float, rng: np.random.Generator, walkers: np.ndarray) -> np.ndarray:
    """A cheap but frame-specific BGR scene: sky, road with lane lines in every tile, the frame number, and the
    ``walkers`` ahead ((N, 2) CARLA ego x forward, y right) in the middle tile as filled rectangles."""
    tiles, tile_width, _ = RIG_MOSAICS[rig]
    h, w = mosaic_shape(rig)
    image = np.full((h, w, 3), (90, 90, 90), np.uint8)
    image[: h // 2] = (200, 160, 110)
    for tile in range(tiles):
        x0 = tile * tile_width + tile_width // 2 + int(shift * 40)
        cv2.line(image, (x0, h // 2), (x0 - 150, h - 1), (255, 255, 255), 4)
        cv2.line(image, (x0, h // 2), (x0 + 150, h - 1), (255, 255, 255), 4)
    cv2.putText(image, f"frame {frame}", (40, 60), cv2.FONT_HERSHEY_SIMPLEX, 1.5, (0, 0, 255), 3)
    image[h // 2 :] += rng.integers(0, 20, (h - h // 2, w, 3), dtype=np.uint8)
    focal = tile_width / (2 * np.tan(np.radians(FRONT_FOV / 2)))
    centre = (tiles // 2) * tile_width + tile_width / 2
    half, tall = pedestrians_ahead.SIZE[1] / 2, pedestrians_ahead.SIZE[2]
    for x, y in sorted(walkers, key=lambda p: -p[0]):
        if x < 1.0:
            continue
        u0, u1 = centre + focal * (y - half) / x, centre + focal * (y + half) / x
        v0, v1 = h / 2 + focal * (CAMERA_HEIGHT - tall) / x, h / 2 + focal * CAMERA_HEIGHT / x
        cv2.rectangle(image, (int(u0), int(v0)), (int(np.ceil(u1)), int(np.ceil(v1))), pedestrians_ahead.COLOUR, -1)
    return image


def semantics(rig: str) -> np.ndarray:
    h, w = mosaic_shape(rig)
    label = np.zeros((h, w), np.uint8)
    label[h // 2 :] = 2  # ROAD
    label[h // 2 + 20 : h // 2 + 30] = 5  # ROAD_LINE
    label[h // 2 - 40 : h // 2, 500:560] = 1  # VEHICLE
    return label


def depth(rig: str, frame: int) -> np.ndarray:
    """Depth in metres per pixel at 1/4 resolution, encoded as LEAD does: clip(d, 0, 50) / 50 * 255."""
    h, w = (side // DEPTH_RATIO for side in mosaic_shape(rig))
    rows = np.linspace(80.0, 2.0, h)[:, None] + np.zeros((1, w)) + 0.1 * frame
    return (np.clip(rows, 0, 50) / 50 * 255).astype(np.uint8)


def hdmap(path: np.ndarray, ego: np.ndarray) -> np.ndarray:
    """Ego-centred ChauffeurNet raster: rows follow ego y (right), columns ego x, 2 px/m, ego centre in the middle."""
    raster = np.zeros((HDMAP_SIZE, HDMAP_SIZE), np.uint8)
    local = points_to_local(path[::10, :2], ego)
    pixels = np.round(local * HDMAP_PX_PER_M + HDMAP_SIZE / 2 - 0.5).astype(np.int32)[:, None, :]
    cv2.polylines(raster, [pixels], False, 1, thickness=int(7 * HDMAP_PX_PER_M))  # ROAD
    cv2.polylines(raster, [pixels], False, 4, thickness=1)  # LANE_MARKERS_BROKEN
    return raster


def lidar_points(boxes: list[dict], rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Points on the box surfaces (sweeps 0..4) and a building facade, in the ego frame, inside the BEV box."""
    clouds, times = [], []
    for box in boxes[1:]:
        local = rng.uniform(-1, 1, (60, 3)) * np.asarray(box["extent"])
        clouds.append(rotate(local, box["yaw"]) + box["position"])
        times.append(rng.integers(0, 5, 60))
    facade = np.column_stack([rng.uniform(-30, 60, 400), np.full(400, 15.0), rng.uniform(0.2, 8, 400)])
    clouds.append(facade)
    times.append(rng.integers(0, 10, 400))
    points = np.concatenate(clouds)
    keep = (points[:, 0] > -32) & (points[:, 0] < 64) & (np.abs(points[:, 1]) < 40)
    keep &= (points[:, 2] > -4) & (points[:, 2] < 10)
    return points[keep], np.concatenate(times)[keep].astype(np.uint8)


#: Realistic LiDAR files (LEAD's expert: sweeps of the last 5 steps, radar of the last 10 appended as points and
#: duplicated within 32 m): non-ground returns per sweep, radar returns per step (4 sensors x 1500 points/s / 20 Hz),
#: duplicates per radar return within the radius.
REALISTIC_LIDAR = {"sweeps": 5, "per_sweep": 10_000, "radar_steps": 10, "radar_per_step": 300, "duplicates": 5}
RADAR_DUPLICATE_RADIUS_M = 32.0
#: Returns per radar sensor and step (1500 points/s at 20 Hz), the size of LEAD's padded radar input per sensor.
RADAR_POINTS_PER_SENSOR = 75


def dense_lidar_points(boxes: list[dict], speed: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Realistic LiDAR file content (:data:`REALISTIC_LIDAR`): per sweep, a third of the returns on the actors'
    boxes and the rest on roadside structures 12-38 m either side, shifted by the ego's motion between sweeps; then
    the radar returns, with their duplicates. Ego frame, inside LEAD's BEV box."""
    spec, clouds, times = REALISTIC_LIDAR, [], []
    actors = [box for box in boxes[1:] if abs(box["position"][0]) < 64 and abs(box["position"][1]) < 40]
    on_boxes = spec["per_sweep"] // 3 // max(len(actors), 1)
    rest = spec["per_sweep"] - on_boxes * len(actors)
    for sweep in range(spec["sweeps"]):
        parts = [
            rotate(rng.uniform(-1, 1, (on_boxes, 3)) * box["extent"], box["yaw"]) + box["position"] for box in actors
        ]
        side = rng.choice([-1.0, 1.0], rest) * rng.uniform(12.0, 38.0, rest)
        parts.append(np.column_stack([rng.uniform(-31.9, 63.9, rest), side, rng.uniform(0.3, 9.5, rest)]))
        clouds.append(np.concatenate(parts) + np.array([speed * sweep / FPS, 0.0, 0.0]))  # the ego moved on since
        times.append(np.full(len(clouds[-1]), sweep))
    movers = [box for box in actors if box.get("speed", 0.0) > 0] or actors
    for step in range(spec["radar_steps"]):
        picks = rng.integers(0, len(movers), spec["radar_per_step"])
        radar = np.asarray([movers[i]["position"] for i in picks]) + rng.normal(0, 0.3, (len(picks), 3))
        near = np.hypot(radar[:, 0], radar[:, 1]) < RADAR_DUPLICATE_RADIUS_M
        radar = np.concatenate([radar, *[radar[near]] * (spec["duplicates"] - 1)])
        clouds.append(radar)
        times.append(np.full(len(radar), step))
    points, time = np.concatenate(clouds), np.concatenate(times)
    keep = (points[:, 0] > -32) & (points[:, 0] < 64) & (np.abs(points[:, 1]) < 40)
    keep &= (points[:, 2] > -4) & (points[:, 2] < 10)
    return points[keep], time[keep].astype(np.uint8)


def write_laz(path: Path, points: np.ndarray, time: np.ndarray) -> None:
    """LAS 1.2, point format 0, 0.1 m scale, offset at the minimum, extra uint8 ``time``, LAZ via lazrs."""
    import laspy

    header = laspy.LasHeader(point_format=0, version="1.2")
    header.add_extra_dim(laspy.ExtraBytesParams(name="time", type=np.uint8))
    header.scales = np.array([0.1, 0.1, 0.1])
    header.offsets = points.min(axis=0) if len(points) else np.zeros(3)
    las = laspy.LasData(header)
    las.x, las.y, las.z = points[:, 0], points[:, 1], points[:, 2]
    las.time = time
    las.write(str(path), laz_backend=laspy.LazBackend.Lazrs)


def radar(boxes: list[dict], rng: np.random.Generator, realistic: bool = False) -> dict[str, np.ndarray]:
    """Four float16 (n, 4) radar clouds: x, y, z, radial velocity of hits on the moving boxes, ego frame; one hit
    per box, or (``realistic``) :data:`RADAR_POINTS_PER_SENSOR` per sensor, spread over the boxes it faces or, where
    it faces none, static clutter (kerbs, poles) in its half of the scene."""
    hits = [box for box in boxes[1:] if "num_radar_points" in box]
    out = {}
    for sensor in range(1, 5):
        ahead = sensor <= 2
        facing = [box for box in hits if (box["position"][0] >= 0) == ahead]
        if realistic and facing:
            facing = [facing[i] for i in rng.integers(0, len(facing), RADAR_POINTS_PER_SENSOR)]
        rows = []
        for box in facing:
            x, y, z = box["position"]
            radial = box["speed"] * np.cos(box["yaw"] - np.arctan2(y, x))
            rows.append([x + rng.normal(0, 0.2), y + rng.normal(0, 0.2), z, radial])
        if realistic and not facing:
            n = RADAR_POINTS_PER_SENSOR
            x = rng.uniform(2.0, 60.0, n) * (1 if ahead else -1)
            rows = np.column_stack([x, rng.uniform(-30.0, 30.0, n), rng.uniform(0.0, 2.0, n), np.zeros(n)])
        out[f"radar{sensor}"] = np.asarray(rows, np.float16).reshape(-1, 4)
    return out
