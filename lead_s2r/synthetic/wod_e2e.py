"""Synthetic WOD-E2E in its on-disk format: TFRecord shards of ``E2EDFrame`` records with real framing and CRCs.

What it mimics (facts in ``shared/research/wod_e2e.md`` §1): one record per 10 Hz frame, records of a split
shuffled across 3 shards, frame ids ``<uuid>-<NNN>`` that do not start at 0 and have gaps, 8 cameras with
JPEGs and calibration, past 16 @ 4 Hz ending at (0, 0) with velocity and acceleration but no z, future 20 @ 4 Hz
(absent in test), intents, validation frames with up to 3 rated trajectories (scores 0-10, some -1 or unset,
some shorter than 20 points), ``timestamp_micros`` = 0 as in the real data, and the scenario-cluster JSON.
:func:`make_dataset` returns the ground truth that :func:`write_dataset` encodes, so tests can compare.

The quickstart trains and scores on it, which sets two more constraints. The future must follow from what a model
sees (speed, acceleration and intent, and the cameras), so each segment keeps its acceleration and yaw rate, except
where the cameras show why not: in a third of the segments (:func:`is_pedestrian_segment`, straight and left) a row
of pedestrians stands in the lane ahead, drawn in the cameras (:mod:`~lead_s2r.synthetic.wod_e2e_camera`), and the
driver brakes to a stop behind it (:mod:`~lead_s2r.synthetic.pedestrians_ahead`) after every frame of the segment
(:data:`BRAKE_AT`), so no frame's ego status differs from a segment without them. Their validation segments are
the scenario cluster ``Pedestrian`` in the cluster file, the one place the real data labels a segment's kind (the
other segments cycle through the other clusters); the adapter tags their samples ``cluster:Pedestrian``.
And RFS only means something if the raters behave like Waymo's: one rated frame per validation segment, and among
its candidates one close to what was driven and mostly rated high, so the logged future scores about 8 (the paper's
Expert: 8.10) and a model that learned the driving lands in that candidate's trust region. With random labels on
random offsets, the Expert scored 5.7 and every model sat on the floor of 4.
"""

import json
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import crc32c
import cv2
import numpy as np

from lead_s2r.geometry import homogeneous, resample, rotate
from lead_s2r.synthetic import pedestrians_ahead, wod_e2e_camera
from lead_s2r.synthetic.wod_e2e_proto import States, camera_calibration, camera_image, e2ed_frame

SHARDS = 3
SHARD_STEMS = {
    "train": "training_202504031202_202504151040",
    "val": "val_202504211836_202504220845",
    "test": "test_202504211836-202504220845",
}
CLUSTER_FILE = "val_sequence_name_to_scenario_cluster.json"
CLUSTERS = ("Construction", "Interections", "Cyclist", "Cut_ins", "Special Vehicles")
PEDESTRIAN_CLUSTER = "Pedestrian"
#: A pedestrian segment brakes this many seconds after its drive starts: after its last frame (at most 5.1 s).
BRAKE_AT = (5.2, 6.0)
#: Rear axle to front bumper of the ego (:data:`lead_s2r_adapters.wod_e2e.VEHICLE`'s Jaguar I-Pace), m.
EGO_FRONT = 1.51 + 4.682 / 2
INTENT = {"straight": 1, "left": 2, "right": 3}
FRAMES_PER_SEGMENT = 12
#: Per segment, drawn uniformly: initial speed (m/s), acceleration (m/s^2), yaw rate per intent (rad/s).
SPEEDS = (3.0, 12.0)
ACCELS = (-0.5, 0.8)
YAW_RATES = {"left": (0.12, 0.3), "straight": (-0.02, 0.02), "right": (-0.3, -0.12)}
#: Label of the rated trajectory closest to the logged one, and how often: mean 8.15.
LOGGED_LABELS = (10, 9, 8, 7, 6, 5)
LOGGED_LABEL_P = (0.2, 0.25, 0.25, 0.15, 0.1, 0.05)
#: Camera name -> (height, width) of the real decoded images, yaw (deg) and mounting position on the vehicle.
CAMERAS = {
    1: (1079, 972, 0.0, (1.52, 0.03, 1.81)),
    2: (1079, 972, 45.0, (1.45, 0.15, 1.81)),
    3: (1079, 972, -45.0, (1.48, -0.12, 1.81)),
    4: (1079, 972, 90.0, (1.10, 0.90, 1.70)),
    5: (1079, 972, -90.0, (1.10, -0.90, 1.70)),
    6: (587, 972, 135.0, (-0.60, 0.70, 1.75)),
    7: (551, 972, 180.0, (-0.90, 0.00, 1.80)),
    8: (587, 972, -135.0, (-0.60, -0.70, 1.75)),
}
IMAGE_SCALE = 1 / 18  # tiny JPEGs; intrinsics are scaled with them so they stay consistent
_PAST_T = 0.25 * (np.arange(16) - 15)
_FUTURE_T = 0.25 * (np.arange(20) + 1)
_SIM_DT = 0.05  # multiple of both the 0.1 s frame step and the 0.25 s state step


@dataclass
class SynthCamera:
    name: int
    jpeg: bytes
    intrinsic: list[float]
    extrinsic: list[float]  # camera -> vehicle, row-major 4x4, Waymo camera axes (x optical axis, y left, z up)
    width: int
    height: int


@dataclass
class SynthFrame:
    """Ground truth of one record."""

    split: str
    sequence: str
    frame_idx: int
    cameras: list[SynthCamera]
    past: np.ndarray  # (16, 6) x, y, vx, vy, ax, ay in the t0 rear-axle frame
    future: np.ndarray | None  # (20, 3) x, y, z
    intent: int
    preferences: list[tuple[np.ndarray, float | None]] = field(default_factory=list)  # (T, 2) xy, score

    @property
    def name(self) -> str:
        return f"{self.sequence}-{self.frame_idx:03d}"


@dataclass
class SynthDataset:
    frames: list[SynthFrame]
    clusters: dict[str, str]


def _cumulative(values: np.ndarray) -> np.ndarray:
    """Trapezoidal integral over time at ``_SIM_DT``, 0 at the first row."""
    return np.concatenate([[0.0], np.cumsum(0.5 * _SIM_DT * (values[1:] + values[:-1]))])


def _drive(duration: float, speed: float, accel: float, yaw_rate: float, brake_at: float | None = None) -> np.ndarray:
    """Global (t, x, y, heading, vx, vy, ax, ay) from t = 0 at ``_SIM_DT``: speed ramps, yaw rate constant; from
    ``brake_at`` a stop (:func:`~lead_s2r.synthetic.pedestrians_ahead.motion`) along the same curve (the yaw rate
    falls with the speed)."""
    t = np.arange(round(duration / _SIM_DT) + 1) * _SIM_DT
    if brake_at is None:
        v = np.maximum(speed + accel * t, 0.5)
        dv = np.where(speed + accel * t > 0.5, accel, 0.0)
        omega = np.full_like(t, yaw_rate)
        heading = yaw_rate * t
    else:
        _, v, dv = pedestrians_ahead.motion(speed, accel, brake_at, t)
        omega = yaw_rate * np.where(t > brake_at, v / (speed + accel * brake_at), 1.0)
        heading = _cumulative(omega)
    vx, vy = v * np.cos(heading), v * np.sin(heading)
    ax = dv * np.cos(heading) - vy * omega
    ay = dv * np.sin(heading) + vx * omega
    return np.stack([t, _cumulative(vx), _cumulative(vy), heading, vx, vy, ax, ay], axis=1)


def is_pedestrian_segment(index: int) -> bool:
    """Whether segment ``index`` of a split has pedestrians ahead: every third, half of the straight and half of
    the left turns (:func:`_segment` cycles left, straight, right), so the intent does not give them away."""
    return index % 6 in (1, 3)


def pedestrian_row(speed: float, accel: float, yaw_rate: float, brake_at: float) -> np.ndarray:
    """Global ground positions (N, 2) of the pedestrians ahead of a drive (:func:`_drive` from the same values):
    across its path, their centre :func:`~lead_s2r.synthetic.pedestrians_ahead.row_distance` along it."""
    stop = pedestrians_ahead.stopping_distance(speed, accel, brake_at)
    duration = brake_at + pedestrians_ahead.brake_duration(speed + accel * brake_at) + 1.0  # past the stop
    track = _drive(duration, speed, accel, yaw_rate, brake_at)
    arc = _cumulative(np.hypot(track[:, 4], track[:, 5]))
    end = track[-1]
    beyond = pedestrians_ahead.row_distance(stop, EGO_FRONT) - arc[-1]  # the path goes straight on after the stop
    centre = end[1:3] + beyond * np.array([np.cos(end[3]), np.sin(end[3])])
    left = np.array([-np.sin(end[3]), np.cos(end[3])])
    return np.array([centre + dy * left for dy in pedestrians_ahead.ROW])


def _local(track: np.ndarray, i0: int, rows: np.ndarray) -> np.ndarray:
    """Rows of ``track`` in the frame of row ``i0``: (N, 6) x, y, vx, vy, ax, ay."""
    sel, heading = track[rows], track[i0, 3]
    pos = rotate(sel[:, 1:3] - track[i0, 1:3], -heading)
    return np.concatenate([pos, rotate(sel[:, 4:6], -heading), rotate(sel[:, 6:8], -heading)], axis=1)


def _camera(name: int, rng: np.random.Generator, scale: float, pedestrians: np.ndarray) -> SynthCamera:
    """Camera ``name``'s calibration and image, ``pedestrians`` (N, 2) on the ground in the vehicle frame."""
    height, width, yaw_deg, (px, py, pz) = CAMERAS[name]
    height, width = round(height * scale), round(width * scale)
    f = 1112.18 * scale
    intrinsic = [f, f * 0.9999, width / 2 + 0.3, height * 0.66, -0.0736, -0.0366, 0.0, 0.0, 0.0]
    yaw, pitch = math.radians(yaw_deg), 0.02  # a slight downward pitch about the camera's y axis
    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    ry = np.array([[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0], [-math.sin(pitch), 0, math.cos(pitch)]])
    extrinsic = homogeneous(rz @ ry, (px, py, pz)).ravel().tolist()
    image = wod_e2e_camera.render((height, width), intrinsic, extrinsic, pedestrians, rng)
    jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 70])[1].tobytes()
    return SynthCamera(name, jpeg, intrinsic, extrinsic, width, height)


def _normals(xy: np.ndarray) -> np.ndarray:
    """Unit left normals (T, 2) of a path that starts at the origin, from backward differences."""
    steps = np.diff(np.vstack([[0.0, 0.0], xy]), axis=0)
    steps /= np.maximum(np.linalg.norm(steps, axis=1, keepdims=True), 1e-9)
    return np.column_stack([-steps[:, 1], steps[:, 0]])


def _candidates(future: np.ndarray, rng: np.random.Generator) -> list[tuple[np.ndarray, float]]:
    """The three trajectories raters score: close to what was driven (mostly rated high: the logged future's RFS
    averages about 8, the paper's Expert 8.10), braking harder along the same path, and swerving 2-3.5 m aside."""
    xy, normals, fraction = future[:, :2], _normals(future[:, :2]), _FUTURE_T / _FUTURE_T[-1]
    near = xy * (1.0 + rng.uniform(-0.02, 0.02)) + normals * rng.uniform(-0.2, 0.2) * fraction[:, None] ** 2
    path = np.vstack([[0.0, 0.0], xy])  # from the origin at t = 0
    slower, _ = resample(np.r_[0.0, _FUTURE_T], path, _FUTURE_T * (1.0 - rng.uniform(0.25, 0.45) * fraction))
    aside = xy + normals * rng.choice([-1.0, 1.0]) * rng.uniform(2.0, 3.5) * np.clip(fraction / 0.6, 0, 1)[:, None]
    labels = (rng.choice(LOGGED_LABELS, p=LOGGED_LABEL_P), rng.integers(3, 10), rng.integers(0, 7))
    return [(traj.astype(np.float32), float(label)) for traj, label in zip((near, slower, aside), labels, strict=True)]


def _preferences(future: np.ndarray, rng: np.random.Generator, variant: int) -> list[tuple[np.ndarray, float | None]]:
    """Rated candidates (:func:`_candidates`) in a random order; ``variant`` puts the awkward cases of the real
    data on the alternatives: a -1 label and a short (11-point) trajectory (issue #985), or a score never set."""
    rated: list[tuple[np.ndarray, float | None]] = list(_candidates(future, rng))
    (slower, slower_label), (aside, _) = rated[1:]
    if variant == 0:
        rated[1:] = [(slower[:11], slower_label), (aside, -1.0)]
    elif variant == 1:
        rated[2] = (aside, None)  # preference_score never set: must not read as the default 0
    return [rated[i] for i in rng.permutation(len(rated))]


def _rated_frames(split: str, index: int, frames: list[int], rng: np.random.Generator) -> list[int]:
    """Validation rates one frame per segment (a random one past the first two); segment 1 of a split has two,
    as one real segment does (issue #942). Training and test frames carry no ratings."""
    if split != "val":
        return []
    picks = rng.choice(len(frames) - 2, size=2 if index == 1 else 1, replace=False) + 2
    return sorted(frames[i] for i in picks)


def _segment(split: str, index: int, rng: np.random.Generator, scale: float) -> list[SynthFrame]:
    sequence = rng.bytes(16).hex()
    kind = ("left", "straight", "right")[index % 3]
    yaw_rate = float(rng.uniform(*YAW_RATES[kind]))
    start = int(rng.integers(5, 40))
    frames = [f for f in range(start, start + FRAMES_PER_SEGMENT) if not (index == 0 and f == start + 5)]
    speed, accel = float(rng.uniform(*SPEEDS)), float(rng.uniform(*ACCELS))
    brake_at = float(rng.uniform(*BRAKE_AT)) if is_pedestrian_segment(index) else None
    track = _drive(0.1 * (frames[-1] - start) + 9.5, speed, accel, yaw_rate, brake_at)
    row = np.empty((0, 2)) if brake_at is None else pedestrian_row(speed, accel, yaw_rate, brake_at)
    rated = _rated_frames(split, index, frames, rng)
    out = []
    for frame_idx in frames:
        i0 = round((0.1 * (frame_idx - start) + 4.0) / _SIM_DT)
        past = _local(track, i0, i0 + np.round(_PAST_T / _SIM_DT).astype(int))
        future_rows = _local(track, i0, i0 + np.round(_FUTURE_T / _SIM_DT).astype(int))
        future = None if split == "test" else np.column_stack([future_rows[:, :2], 0.02 * np.arange(20)])
        preferences: list[tuple[np.ndarray, float | None]] = []
        if frame_idx in rated:
            preferences = _preferences(future, rng, variant=(rated.index(frame_idx) + index) % 3)
        elif split == "val" and index % 3 == 2:
            preferences = [(future[:, :2].astype(np.float32), -1.0)] * 3  # unrated frame carrying -1 labels
        seen = rotate(row - track[i0, 1:3], -track[i0, 3])  # the pedestrians in the t0 vehicle frame
        cameras = [_camera(name, rng, scale, seen) for name in CAMERAS]
        out.append(SynthFrame(split, sequence, frame_idx, cameras, past, future, INTENT[kind], preferences))
    return out


def make_dataset(
    count: int | None = None, seed: int = 0, image_scale: float = IMAGE_SCALE, splits: dict[str, int] | None = None
) -> SynthDataset:
    """Ground truth: ``count`` segments (default 3) in each of train, val and test, or ``splits`` (split -> segments;
    splits left out get none); images at ``image_scale``. Every split draws its segments from one distribution
    (speeds, accelerations, turn kinds), so a model trained on train can be judged on val."""
    rng = np.random.default_rng(seed)
    splits = splits or dict.fromkeys(SHARD_STEMS, 3 if count is None else count)
    frames: list[SynthFrame] = []
    clusters: dict[str, str] = {}
    for split in SHARD_STEMS:
        for index in range(splits.get(split, 0)):
            segment = _segment(split, index, rng, image_scale)
            frames.extend(segment)
            if split == "val":
                pedestrians = is_pedestrian_segment(index)
                clusters[segment[0].sequence] = PEDESTRIAN_CLUSTER if pedestrians else CLUSTERS[index % len(CLUSTERS)]
    return SynthDataset(frames, clusters)


def _masked_crc(data: bytes) -> int:
    crc = crc32c.crc32c(data)
    return ((crc >> 15 | crc << 17) & 0xFFFFFFFF) + 0xA282EAD8 & 0xFFFFFFFF


def frame_record(payload: bytes) -> bytes:
    """TFRecord framing: length, masked CRC of the length, payload, masked CRC of the payload."""
    length = struct.pack("<Q", len(payload))
    return length + struct.pack("<I", _masked_crc(length)) + payload + struct.pack("<I", _masked_crc(payload))


def encode_frame(frame: SynthFrame) -> bytes:
    """The serialized ``E2EDFrame`` of one ground-truth frame (cameras in a shuffled-looking fixed order)."""
    order = [frame.cameras[i] for i in (3, 0, 7, 1, 5, 2, 6, 4)]
    images = [camera_image(c.name, c.jpeg) for c in order]
    calibrations = [camera_calibration(c.name, c.intrinsic, c.extrinsic, c.width, c.height) for c in reversed(order)]
    p = frame.past.astype(np.float32)
    past = States(p[:, 0], p[:, 1], vel_x=p[:, 2], vel_y=p[:, 3], accel_x=p[:, 4], accel_y=p[:, 5])
    future = None if frame.future is None else States(*frame.future.astype(np.float32).T)  # x, y, z
    preferences = [States(xy[:, 0], xy[:, 1], preference_score=score) for xy, score in frame.preferences]
    return e2ed_frame(frame.name, images, calibrations, past, future, frame.intent, preferences)


def shard_path(out: Path, split: str, shard: int) -> Path:
    return Path(out) / f"{SHARD_STEMS[split]}.tfrecord-{shard:05d}-of-{SHARDS:05d}"


def write_dataset(out: Path, dataset: SynthDataset, seed: int = 0) -> list[Path]:
    """Every split's records shuffled over :data:`SHARDS` shards (none for a split without frames); the cluster JSON."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    paths = []
    for split in SHARD_STEMS:
        frames = [f for f in dataset.frames if f.split == split]
        if not frames:
            continue
        order = rng.permutation(len(frames))
        for shard in range(SHARDS):
            path = shard_path(out, split, shard)
            path.write_bytes(b"".join(frame_record(encode_frame(frames[i])) for i in order[shard::SHARDS]))
            paths.append(path)
    clusters = {uuid: {"scenario_cluster": name} for uuid, name in dataset.clusters.items()}
    (out / CLUSTER_FILE).write_text(json.dumps(clusters, indent=1))
    return paths


def generate(
    out: Path,
    count: int | None = None,
    seed: int = 0,
    splits: dict[str, int] | None = None,
    image_scale: float = IMAGE_SCALE,
) -> None:
    """``lead-s2r synth wod_e2e --out DIR [--segments N]``: N segments per split (default 3), or ``splits``; images
    at ``image_scale`` (1.0: the real cameras' sizes, which take the loader's reduced-decode path)."""
    write_dataset(out, make_dataset(count, seed, image_scale, splits), seed)
