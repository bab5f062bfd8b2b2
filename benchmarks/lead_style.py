"""A LEAD-style per-file CARLA loader for the loader benchmark: LEAD's steps per frame and LEAD's tensor contract.

It mirrors what LEAD's ``CARLAData.__getitem__`` does when no cache holds the frame (facts:
shared/research/lead_repo.md §1.3-1.7; LEAD's ``carla_dataset.py`` / ``carla_dataset_utils.py``): read the meta's
LZMA pickle and build the planning targets from it (waypoints every 5th 20 Hz future pose, the route smoothed to 1 m
steps, target points from ``next_target_points_3.25`` turned into the ego frame, a one-hot command); then, per rig
it builds (``views``: LEAD builds the normal *and* the perturbated rig whenever the frame is not cached, and keeps
one), the sensor data: the JPEG decoded and turned to RGB, the four radar clouds from their npz, the LAZ read with
laspy, filtered to the sweeps in use, re-aligned to the rig and splatted into a 2-D histogram (``np.histogramdd``,
which LEAD runs twice: once over every point, a result it discards, and once after the height filter), the semantic,
hdmap (through a class lookup) and depth PNGs, the box pickle turned into LEAD's (90, 9) pixel-system boxes with each
box's future waypoints, and the BEV occupancy drawn box by box into a 1024x1024 canvas. Finally the labels in LEAD's
contract: float32 (1, H, W) LiDAR raster, uint8 RGB (3, H, W), full-size uint8 semantics, depth decoded to metres
and upsampled 4x to the image (float32), int64 BEV semantics (hdmap cut, doubled, occupancy overlaid), dense
CenterNet target maps, radar (300, 5) and radar detections (20, 4); collated by torch's ``default_collate``.

Left out, as in our loader: LEAD's colour augmentation (imgaug) and its choice of the perturbated rig for training
(the normal rig's tensors are returned), and the optional caches. Class remapping follows LEAD's main cases (the
scenario-specific relabelling of a few boxes costs a dictionary lookup each and is left out).
"""

import lzma
import math
import pickle
from pathlib import Path
from typing import Any

import cv2
import laspy
import numpy as np
from torch.utils.data import Dataset

# LEAD's Leaderboard training configuration (TrainingConfig), the values these steps read.
MIN_X, MAX_X, MIN_Y, MAX_Y, PIXELS_PER_METER = -32, 64, -40, 40, 4
HIST_MAX_PER_PIXEL = 5
MIN_HEIGHT_LIDAR, MAX_HEIGHT_LIDAR = -100.0, 100.0
LIDAR_STEPS = 10
RADAR_SENSORS, RADAR_POINTS_PER_SENSOR, RADAR_QUERIES = 4, 75, 20
MAX_BOXES, WAYPOINTS, WAYPOINT_SPACING, MAX_FUTURE_JUMP_M = 90, 8, 5, 10.0
BEV_DOWNSAMPLE, BOX_CLASSES, YAW_BINS = 4, 8, 12
ROUTE_POINTS_SMOOTHING, ROUTE_POINTS = 20, 10
TP_POP_DISTANCE = 3.25
DEPTH_MAX_M, DEPTH_RATIO = 50.0, 4
HDMAP_PIXELS_PER_METER = 2
OCCUPANCY_SCALE, OCCUPANCY_SIZE = 4, 1024
BEV_OCCUPANCY_OFFSET = 3  # 13 BEV semantic classes, of which the last 10 are occupancy classes
MIN_LIDAR_POINTS, MIN_VISIBLE_PIXELS = 1, 10
#: ChauffeurNet hdmap ids -> TransFuser BEV ids (LEAD's ``hdmap_converter``): an int64 lookup table.
HDMAP_CONVERTER = np.zeros(256, np.int64)
HDMAP_CONVERTER[[1, 2, 3, 4, 5]] = [1, 1, 2, 2, 3]
#: LEAD's box classes by bbox ``class``: VEHICLE 0, WALKER 1, TRAFFIC_LIGHT 2, STOP_SIGN 3, ..., PARKING 6.
BOX_CLASS = {"car": 0, "walker": 1, "traffic_light": 2, "stop_sign": 3, "static": 6}
#: BEV occupancy classes by bbox ``class`` (VEHICLE 1, WALKER 2, OBSTACLE 3, traffic light red 8).
OCCUPANCY_CLASS = {"car": 1, "walker": 2, "static": 3, "traffic_light": 8}


def read_pickle(path: Path) -> Any:
    """LEAD's ``read_pickle``: an LZMA stream holding a pickle (plain ``pickle``, as LEAD loads it)."""
    with lzma.open(path, "rb") as file:
        return pickle.load(file)


def rotation(yaw_deg: float) -> np.ndarray:
    yaw = math.radians(yaw_deg)
    return np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])


def perturbate(points: np.ndarray, translation: float, rotation_deg: float) -> np.ndarray:
    """Points (N, 2) in the rig shifted sideways by ``translation`` m and turned by ``rotation_deg``."""
    return (rotation(rotation_deg).T @ (np.asarray(points, np.float64) - [0.0, translation]).T).T


def smooth_route(route: np.ndarray) -> np.ndarray:
    """Points along ``route`` at 2.5 m, 3.5 m, ... of arc length (LEAD's ``smooth_path``)."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=1))])
    targets = 2.5 + np.arange(ROUTE_POINTS, dtype=np.float64)
    return np.column_stack([np.interp(targets, arc, route[:, 0]), np.interp(targets, arc, route[:, 1])])


def splat(points: np.ndarray) -> np.ndarray:
    """LEAD's ``splat_points``: a 2-D histogram at 4 px/m over the BEV box, clipped at 5 and scaled to [0, 1]."""
    xbins = np.linspace(MIN_X, MAX_X, (MAX_X - MIN_X) * PIXELS_PER_METER + 1)
    ybins = np.linspace(MIN_Y, MAX_Y, (MAX_Y - MIN_Y) * PIXELS_PER_METER + 1)
    hist = np.histogramdd(points[:, :2], bins=(xbins, ybins))[0]
    hist[hist > HIST_MAX_PER_PIXEL] = HIST_MAX_PER_PIXEL
    return (hist / HIST_MAX_PER_PIXEL).T


def rasterize_lidar(points: np.ndarray) -> np.ndarray:
    """LEAD's ``rasterize_lidar``: the splat over every point (discarded, as LEAD does), then over the points in
    the height band, float32 (H, W)."""
    splat(points)
    points = points[(points[:, 2] <= MAX_HEIGHT_LIDAR) & (points[:, 2] >= MIN_HEIGHT_LIDAR)]
    return np.stack([splat(points)], axis=-1).squeeze().astype(np.float32)


def box_row(box: dict, translation: float, rotation_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """LEAD's ``bbox_json2array``: [x, y, half length, half width, yaw, speed, brake, class, radar points] in the
    rig's frame, and the box's future waypoints (8 at 4 Hz, extrapolated at constant velocity past its end)."""
    x, y = perturbate(np.array([box["position"][:2]]), translation, rotation_deg)[0]
    yaw = (box["yaw"] - math.radians(rotation_deg) + math.pi) % (2 * math.pi) - math.pi
    row = np.array(
        [x, y, box["extent"][0], box["extent"][1], yaw, box.get("speed", 0.0), float(box.get("brake", 0.0)),
         BOX_CLASS.get(box["class"], 0), box.get("num_radar_points", -1)],
        np.float32,
    )  # fmt: skip
    waypoints = np.repeat([box["position"][:2]], WAYPOINTS, axis=0).astype(np.float32)
    future = box.get("future_positions")
    if future is not None:
        last, count = np.asarray(box["position"][:2], np.float64), 0
        for i in range(WAYPOINTS):
            index = (i + 1) * WAYPOINT_SPACING
            if index >= len(future) or np.linalg.norm(last - future[index]) > MAX_FUTURE_JUMP_M:
                break
            waypoints[i], last, count = future[index], np.asarray(future[index], np.float64), count + 1
        step = box.get("speed", 0.0) / (WAYPOINT_SPACING - 1) * np.array([math.cos(box["yaw"]), math.sin(box["yaw"])])
        for i in range(count, WAYPOINTS):
            last = last + step
            waypoints[i] = last
        waypoints = perturbate(waypoints, translation, rotation_deg).astype(np.float32)
    return row, waypoints


def bbox_labels(boxes: list[dict], translation: float, rotation_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """LEAD's ``get_bbox_labels``: every box converted, then filtered (occlusion, traffic lights that do not
    affect the ego or are green, the BEV box), moved to the pixel system and padded to (90, 9)."""
    rows, waypoints = [], []
    for box in boxes:
        row, future = box_row(box, translation, rotation_deg)
        cls = box["class"]
        if cls == "ego_car":
            continue
        if (
            0 <= box.get("num_points", -1) < MIN_LIDAR_POINTS
            and 0 <= box.get("visible_pixels", -1) < MIN_VISIBLE_PIXELS
        ):
            continue
        if cls == "traffic_light" and (not box.get("affects_ego") or box.get("state") == "Green"):
            continue
        if not (MIN_X < row[0] < MAX_X and MIN_Y < row[1] < MAX_Y and -4 < box["position"][2] < 10):
            continue
        row[:2] -= [MIN_X, MIN_Y]
        row[:4] *= PIXELS_PER_METER
        rows.append(row)
        waypoints.append(future)
    padded = np.zeros((MAX_BOXES, 9), np.float32)
    padded_waypoints = np.zeros((MAX_BOXES, WAYPOINTS, 2), np.float32)
    n = min(len(rows), MAX_BOXES)
    if n:
        padded[:n], padded_waypoints[:n] = np.array(rows)[:n], np.array(waypoints)[:n]
    return padded, padded_waypoints


def bev_occupancy(boxes: list[dict], translation: float, rotation_deg: float) -> np.ndarray:
    """LEAD's ``build_bev_occupancy``: each box's rotated rectangle filled into a 1024x1024 uint8 canvas at 4 px/m."""
    bev = np.zeros((OCCUPANCY_SIZE, OCCUPANCY_SIZE), np.uint8)
    for box in boxes:
        label = OCCUPANCY_CLASS.get(box["class"])
        if label is None or (box["class"] == "traffic_light" and not box.get("affects_ego")):
            continue
        x, y = perturbate(np.array([box["position"][:2]]), translation, rotation_deg)[0]
        cx, cy = (x + 128.0) * OCCUPANCY_SCALE, (128.0 + y) * OCCUPANCY_SCALE
        if not (0 <= cx < OCCUPANCY_SIZE and 0 <= cy < OCCUPANCY_SIZE):
            continue
        size = (box["extent"][0] * 2 * OCCUPANCY_SCALE, box["extent"][1] * 2 * OCCUPANCY_SCALE)
        yaw = math.degrees(box["yaw"]) - rotation_deg
        cv2.fillPoly(bev, [cv2.boxPoints(((cx, cy), size, yaw)).astype(np.int32)], label)
    return bev


def gaussian_radius(height: float, width: float, min_overlap: float = 0.1) -> float:
    """CenterNet's Gaussian radius: the smallest of the three corner-overlap cases (LEAD's ``gaussian_radius``)."""
    r1 = (
        height + width + math.sqrt((height + width) ** 2 - 4 * height * width * (1 - min_overlap) / (1 + min_overlap))
    ) / 2
    b3 = -2 * min_overlap * (height + width)
    c3 = (min_overlap - 1) * width * height
    r3 = (b3 + math.sqrt(b3**2 - 16 * min_overlap * c3)) / 2
    b2 = 2 * (height + width)
    r2 = (b2 + math.sqrt(b2**2 - 16 * (1 - min_overlap) * width * height)) / 2
    return min(r1, r2, r3)


def draw_gaussian(heatmap: np.ndarray, col: int, row: int, radius: int) -> None:
    """A (2r+1)^2 Gaussian of sigma (2r+1)/6 max-blended at (row, col) (LEAD's ``gen_gaussian_target``)."""
    diameter = 2 * radius + 1
    offsets = np.arange(-radius, radius + 1)
    kernel = np.exp(-(offsets[:, None] ** 2 + offsets[None, :] ** 2) / (2 * (diameter / 6) ** 2))
    h, w = heatmap.shape
    left, right, top, bottom = min(col, radius), min(w - col, radius + 1), min(row, radius), min(h - row, radius + 1)
    window = heatmap[row - top : row + bottom, col - left : col + right]
    np.maximum(window, kernel[radius - top : radius + bottom, radius - left : radius + right], out=window)


def centernet_labels(boxes: np.ndarray) -> dict[str, np.ndarray]:
    """LEAD's ``get_centernet_labels``: the heatmap and dense per-cell regression targets at stride 4."""
    h, w = (MAX_Y - MIN_Y) * PIXELS_PER_METER // BEV_DOWNSAMPLE, (MAX_X - MIN_X) * PIXELS_PER_METER // BEV_DOWNSAMPLE
    out = {
        "center_net_heatmap": np.zeros((BOX_CLASSES, h, w), np.float32),
        "center_net_wh": np.zeros((2, h, w), np.float32),
        "center_net_offset": np.zeros((2, h, w), np.float32),
        "center_net_yaw_class": np.zeros((h, w), np.int32),
        "center_net_yaw_res": np.zeros((1, h, w), np.float32),
        "center_net_velocity": np.zeros((1, h, w), np.float32),
        "center_net_brake": np.zeros((h, w), np.int32),
        "center_net_pixel_weight": np.zeros((2, h, w), np.float32),
    }
    for box in boxes[boxes[:, 2] > 0]:  # padding rows have no extent
        cx, cy = box[0] / BEV_DOWNSAMPLE, box[1] / BEV_DOWNSAMPLE
        col, row = int(cx), int(cy)
        if not (0 <= col < w and 0 <= row < h):
            continue
        ex, ey = box[2] / BEV_DOWNSAMPLE, box[3] / BEV_DOWNSAMPLE
        draw_gaussian(out["center_net_heatmap"][int(box[7])], col, row, max(2, int(gaussian_radius(ey, ex))))
        out["center_net_wh"][:, row, col] = ex, ey
        bin_width = 2 * math.pi / YAW_BINS
        yaw = float(box[4]) % (2 * math.pi)
        out["center_net_yaw_class"][row, col] = int(yaw / bin_width)
        out["center_net_yaw_res"][0, row, col] = yaw - (int(yaw / bin_width) + 0.5) * bin_width
        out["center_net_velocity"][0, row, col] = box[5]
        out["center_net_brake"][row, col] = round(float(box[6]))
        out["center_net_offset"][:, row, col] = cx - col, cy - row
        out["center_net_pixel_weight"][:, row, col] = 1.0
    out["center_net_avg_factor"] = np.array(max(1, int((out["center_net_heatmap"] == 1).sum())))
    return out


def radar_input(clouds: dict[str, np.ndarray]) -> np.ndarray:
    """LEAD's ``preprocess_radar_input``: each sensor's points in the BEV box, padded/cut to 75, with its id."""
    per_sensor = []
    for i in range(1, RADAR_SENSORS + 1):
        cloud = clouds[f"radar{i}"]
        inside = cloud[
            (cloud[:, 0] >= MIN_X) & (cloud[:, 0] <= MAX_X) & (cloud[:, 1] >= MIN_Y) & (cloud[:, 1] <= MAX_Y)
        ]
        padded = np.zeros((RADAR_POINTS_PER_SENSOR, 4), np.float32)
        padded[: min(len(inside), RADAR_POINTS_PER_SENSOR)] = inside[:RADAR_POINTS_PER_SENSOR]
        per_sensor.append(np.concatenate([padded, np.full((RADAR_POINTS_PER_SENSOR, 1), i - 1, np.float32)], 1))
    return np.concatenate(per_sensor)


def radar_detections(boxes: np.ndarray) -> np.ndarray:
    """LEAD's radar labels: up to 20 boxes with radar hits, fastest first, as [x, y, speed, valid] in metres."""
    hit = boxes[(boxes[:, 8] > 0) & (boxes[:, 2] > 0)]
    hit = hit[np.argsort(-hit[:, 5], kind="stable")][:RADAR_QUERIES]
    out = np.zeros((RADAR_QUERIES, 4), np.float32)
    out[: len(hit), :2] = hit[:, :2] / PIXELS_PER_METER + [MIN_X, MIN_Y]
    out[: len(hit), 2], out[: len(hit), 3] = hit[:, 5], 1.0
    return out


class LeadStyleFrames(Dataset):
    """One item per frame of the LEAD route folders under ``root`` (``<root>/data/<scenario>/<route>/``), in LEAD's
    tensor contract (module docstring). ``views``: rigs built per item, 2 as LEAD does without a cache (normal and
    perturbated), 1 for the normal only."""

    def __init__(self, root: Path, views: int = 2) -> None:
        self.views = views
        self.frames = sorted(Path(root).glob("data/*/*/bboxes/*.pkl"))

    def __len__(self) -> int:
        return len(self.frames)

    def key(self, index: int) -> str:
        """``<scenario>/<route>/<frame>`` of item ``index``."""
        path = self.frames[index]
        return f"{path.parents[2].name}/{path.parents[1].name}/{path.stem}"

    def __getitem__(self, index: int) -> dict[str, Any]:
        folder, name = self.frames[index].parents[1], self.frames[index].stem
        meta = read_pickle(folder / "metas" / f"{name}.pkl")
        data = {"key": self.key(index), **planning_targets(meta)}
        built = [sensor_data(folder, name, meta, perturbated=view == 1) for view in range(self.views)]
        return data | built[0]  # the normal rig's (the perturbated one is built and dropped, as LEAD does uncached)


def planning_targets(meta: dict) -> dict[str, Any]:
    """The meta's half of LEAD's item: scalars, waypoints, the smoothed route, target points and the command."""
    future = np.asarray(meta["future_positions"])
    indices = [WAYPOINT_SPACING * (i + 1) for i in range(WAYPOINTS)]
    waypoints = np.array([future[i][:2] for i in indices if i < len(future)]).reshape(-1, 2)
    yaws = np.array([meta["future_yaws"][i] for i in indices if i < len(future)])
    out = {
        "speed": float(meta["speed"]),
        "target_speed": float(meta["target_speed"]),
        "brake": float(meta["brake"]),
        "future_waypoints": np.pad(waypoints, ((0, WAYPOINTS - len(waypoints)), (0, 0))).astype(np.float32),
        "future_yaws": np.pad(yaws, (0, WAYPOINTS - len(yaws))).astype(np.float32),
        "route": smooth_route(np.asarray(meta["route"][:ROUTE_POINTS_SMOOTHING], np.float64)).astype(np.float32),
    }
    position, theta = np.asarray(meta["pos_global"][:2]), float(meta["theta"])
    points, commands = [], []
    for point, command in zip(
        meta[f"next_target_points_{TP_POP_DISTANCE}"], meta[f"next_commands_{TP_POP_DISTANCE}"], strict=False
    ):
        if not points or not np.allclose(point[:2], points[-1][:2]):
            points.append(point)
            commands.append(command)
    while len(points) < 3:
        points.append(points[-1])
        commands.append(commands[-1])
    ego = (rotation(math.degrees(theta)).T @ (np.asarray([p[:2] for p in points[:3]]) - position).T).T
    out["target_point_previous"], out["target_point"], out["target_point_next"] = ego.astype(np.float32)
    command = np.zeros(6, np.float32)
    command[max(int(commands[0]) - 1, 0) if int(commands[0]) >= 1 else 3] = 1.0
    out["command"] = command
    return out


def sensor_data(folder: Path, name: str, meta: dict, perturbated: bool) -> dict[str, np.ndarray]:
    """One rig's sensor half of LEAD's item, read from the frame's files and turned into LEAD's tensors."""
    suffix = "_perturbated" if perturbated else ""
    translation = float(meta["perturbation_translation"]) if perturbated else 0.0
    rotation_deg = float(meta["perturbation_rotation"]) if perturbated else 0.0
    image = cv2.imdecode(np.frombuffer((folder / f"rgb{suffix}" / f"{name}.jpg").read_bytes(), np.uint8), -1)
    image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    with np.load(folder / f"radar{suffix}" / f"{name}.npz", allow_pickle=True) as npz:
        radars = {f"radar{i}": npz[f"radar{i}"] for i in range(1, RADAR_SENSORS + 1)}
    las = laspy.read(str(folder / "lidar" / f"{name}.laz"))
    points = las.xyz[las["time"] < LIDAR_STEPS]
    points[:, :2] = perturbate(points[:, :2], translation, rotation_deg)  # LEAD's align_lidar
    semantic = cv2.imread(str(folder / f"semantics{suffix}" / f"{name}.png"), cv2.IMREAD_UNCHANGED)
    hdmap = HDMAP_CONVERTER[cv2.imread(str(folder / f"hdmap{suffix}" / f"{name}.png"), cv2.IMREAD_UNCHANGED)]
    depth = cv2.imread(str(folder / f"depth{suffix}" / f"{name}.png"), cv2.IMREAD_UNCHANGED) / 255.0 * DEPTH_MAX_M
    boxes_json = read_pickle(folder / "bboxes" / f"{name}.pkl")
    boxes, box_waypoints = bbox_labels(boxes_json, translation, rotation_deg)
    occupancy = bev_occupancy(boxes_json, translation, rotation_deg)

    depth = depth.astype(np.float32)
    depth = cv2.resize(
        depth, (depth.shape[1] * DEPTH_RATIO, depth.shape[0] * DEPTH_RATIO), interpolation=cv2.INTER_LINEAR
    )
    centre = hdmap.shape[0] / 2
    xs = (centre + np.array([MIN_X, MAX_X]) * HDMAP_PIXELS_PER_METER).astype(int)
    ys = (centre + np.array([MIN_Y, MAX_Y]) * HDMAP_PIXELS_PER_METER).astype(int)
    bev = hdmap[ys[0] : ys[1], xs[0] : xs[1]].repeat(2, axis=0).repeat(2, axis=1)
    centre = OCCUPANCY_SIZE / 2
    xs = (centre + np.array([MIN_X, MAX_X]) * OCCUPANCY_SCALE).astype(int)
    ys = (centre + np.array([MIN_Y, MAX_Y]) * OCCUPANCY_SCALE).astype(int)
    occupied = occupancy[ys[0] : ys[1], xs[0] : xs[1]]
    mask = occupied != 0
    bev[mask] = occupied[mask] + BEV_OCCUPANCY_OFFSET
    return {
        "rasterized_lidar": rasterize_lidar(points)[None],
        "rgb": np.transpose(image, (2, 0, 1)),
        "radar": radar_input(radars),
        "radar_detections": radar_detections(boxes),
        "semantic": semantic,
        "depth": depth,
        "bev_semantic": bev,
        "center_net_bounding_boxes": boxes,
        "center_net_box_waypoints": box_waypoints,
        **centernet_labels(boxes),
    }
