"""WOD-E2E adapter: TFRecord shards of ``E2EDFrame`` records -> schema v1 samples, without TensorFlow.

A log is one sequence (segment); a sample is one 10 Hz frame. Records of a sequence are shuffled across all
shards of a split, so :meth:`WodE2EAdapter.list_logs` makes one indexing pass per split (``shard, offset,
length, sequence, frame, has_future, n_rated``; cached as parquet under ``index_dir``) and each log carries
the byte ranges of its frames; workers read them by random access in frame order.

Bad records (CRC mismatch, truncated tail, a payload that is not an ``E2EDFrame``) are found by the indexing
pass: each is left out with a record naming shard and offset (:meth:`WodE2EAdapter.bad_records`; the conversion
reports them in errors.jsonl, its summary line and its exit status) and every other record converts;
``strict=True`` makes any of them fail ``list_logs`` instead. A record that goes bad after indexing fails its
log in the worker, with the same shard/offset message.

WOD-E2E trajectories are already in our frame (ISO 8855, origin at the rear axle at t0): nothing is flipped.
"""

import itertools
import json
import re
import statistics
from collections import Counter
from collections.abc import Iterator
from itertools import groupby
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
from google.protobuf.message import DecodeError

from lead_s2r.errors import UserError
from lead_s2r.registry import Adapter, LogRef
from lead_s2r.schema import SCHEMA_VERSION, Command, make_key
from lead_s2r_adapters.tfrecord import RecordReader, cached_index
from lead_s2r_adapters.wod_e2e_proto import E2EDFrame

#: Waymo ``CameraName`` -> (our camera id: the native name in lower case, native name).
NATIVE_CAMERAS = ("FRONT", "FRONT_LEFT", "FRONT_RIGHT", "SIDE_LEFT", "SIDE_RIGHT", "REAR_LEFT", "REAR", "REAR_RIGHT")
CAMERAS = {number: (native.lower(), native) for number, native in enumerate(NATIVE_CAMERAS, 1)}
#: ``EgoIntent.Intent`` -> unified command (UNKNOWN, GO_STRAIGHT, GO_LEFT, GO_RIGHT).
INTENTS = {0: Command.UNKNOWN, 1: Command.STRAIGHT, 2: Command.LEFT, 3: Command.RIGHT}
#: Shard-name prefix -> split (``training_...tfrecord-00000-of-00263``).
SPLITS = {"training": "train", "train": "train", "validation": "val", "val": "val", "testing": "test", "test": "test"}
CLUSTER_GLOB = "*sequence_name_to_scenario_cluster.json"
SHARD_NAME = re.compile(r"^(?P<set>.+)-(?P<index>\d+)-of-(?P<count>\d+)$")
STATE_DT = 0.25  # past and future states are 4 Hz
FRAME_DT_US = 100_000  # frames are 10 Hz; the records' timestamp_micros is 0, so time comes from the index
#: Waymo camera axes (x along the optical axis, y left, z up) from OpenCV's (x right, y down, z forward).
OPENCV_TO_WAYMO = np.array([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)
#: WOD-E2E does not state its vehicle; nominal Jaguar I-PACE figures (Waymo's 5th-generation platform).
VEHICLE = {"length": 4.682, "width": 2.011, "wheel_base": 2.990, "rear_axle_to_center": 1.51}
MIN_SPEED_FOR_YAW_RATE = 0.5
INDEX_SCHEMA = {"sequence": pa.string(), "frame": pa.int32(), "has_future": pa.bool_(), "n_rated": pa.int32()}


class WodE2EError(UserError, ValueError):
    """A record whose content breaks what the adapter expects; names the shard, offset and field."""


def parse_frame(payload: bytes) -> E2EDFrame:
    """Parse one record; ValueError if it is not an ``E2EDFrame`` (undecodable, or no ``frame.context.name``)."""
    try:
        message = E2EDFrame.FromString(payload)
    except DecodeError as err:
        raise WodE2EError(f"not an E2EDFrame ({err})") from None
    split_name(message.frame.context.name)
    return message


def split_name(name: str) -> tuple[str, int]:
    """``'<sequence uuid>-<frame index>'`` -> (uuid, index)."""
    sequence, _, frame = name.rpartition("-")
    if not sequence or not frame.isdigit():
        raise WodE2EError(f"not an E2EDFrame: frame.context.name {name!r} is not '<sequence>-<frame index>'")
    return sequence, int(frame)


def _rated(states: Any) -> bool:
    """A usable rater trajectory: a score that was set and is not the -1 'no label' marker, and some points."""
    return states.HasField("preference_score") and states.preference_score >= 0 and len(states.pos_x) > 0


def _index_columns(payload: bytes) -> dict[str, Any]:
    message = parse_frame(payload)
    sequence, frame = split_name(message.frame.context.name)
    return {
        "sequence": sequence,
        "frame": frame,
        "has_future": len(message.future_states.pos_x) > 0,
        "n_rated": sum(1 for p in message.preference_trajectories if _rated(p)),
    }


def find_shards(src: Path) -> dict[str, list[Path]]:
    """TFRecord shards under ``src`` grouped by split, which is read from the name prefix (``val_...``)."""
    shards: dict[str, list[Path]] = {}
    for path in sorted(Path(src).rglob("*.tfrecord*")):
        if not path.is_file():
            continue
        prefix = path.name.split(".")[0].replace("-", "_").split("_")[0].lower()
        if prefix not in SPLITS:
            raise WodE2EError(f"{path}: cannot tell its split; expected the name to start with one of {sorted(SPLITS)}")
        shards.setdefault(SPLITS[prefix], []).append(path)
    if not shards:
        raise FileNotFoundError(f"no WOD-E2E TFRecord shards (*.tfrecord*) under {src}")
    return shards


def shard_sets(shards: list[Path]) -> dict[tuple[Path, str, int], list[tuple[int, Path]]]:
    """Shards named as one of a set (``<name>.tfrecord-00001-of-00003``): (folder, name, N) -> (index, path) each."""
    sets: dict[tuple[Path, str, int], list[tuple[int, Path]]] = {}
    for path in shards:
        match = SHARD_NAME.match(path.name)
        if match:
            sets.setdefault((path.parent, match["set"], int(match["count"])), []).append((int(match["index"]), path))
    return sets


def missing_shards(shards: list[Path]) -> list[Path]:
    """Files a shard set names but lacks: ``<name>.tfrecord-00001-of-00003`` says its set has three files. Records of
    a segment are shuffled over every shard of its split, so a set short of one file leaves most of its segments short
    of frames, and nothing else tells."""
    return [
        folder / f"{name}-{index:05d}-of-{count:05d}"
        for (folder, name, count), members in sorted(shard_sets(shards).items())
        for index in sorted(set(range(count)) - {present for present, _ in members})
    ]


def thin_shards(shards: list[Path], records: Counter[str]) -> list[str]:
    """Shards of an ``-of-N`` set (N > 1) that exist but hold no record, or fewer than half the median of their set's
    (``records``: indexed records by shard path), each named with its count: a file cut at a record boundary or
    emptied in a copy frames cleanly, and without this the frames it held vanish from their segments unreported.
    The set's last shard may hold a writer's remainder, so it is held to "not empty" only."""
    thin = []
    sets = {key: members for key, members in shard_sets(shards).items() if key[2] > 1}
    for (_, _, count), members in sorted(sets.items()):
        median = statistics.median(records[str(path)] for _, path in members)
        for index, path in sorted(members):
            held = records[str(path)]
            if held == 0 or (index < count - 1 and held < median / 2):
                thin.append(f"{path} (holds {held} records, its set's shards a median of {median:g})")
    return thin


def frame_gaps(frames: list[int]) -> list[str]:
    """The frame indices missing between a segment's first and last (sorted) frames, as ``"12"`` or ``"12-14"``.
    WOD-E2E's own segments have such gaps (its 10 Hz grid is not complete), so they are named in info.json
    (``frame_gaps``), not failed; a file cut short is caught by :func:`thin_shards`."""
    return [
        f"{before + 1}" if after - before == 2 else f"{before + 1}-{after - 1}"
        for before, after in itertools.pairwise(frames)
        if after - before > 1
    ]


def load_clusters(src: Path) -> dict[str, str]:
    """Sequence uuid -> scenario cluster, from ``val_sequence_name_to_scenario_cluster.json`` if present."""
    clusters: dict[str, str] = {}
    for path in sorted(Path(src).rglob(CLUSTER_GLOB)):
        try:
            mapping = json.loads(path.read_bytes())
        except ValueError as err:  # JSONDecodeError, UnicodeDecodeError
            raise WodE2EError(f"{path}: not valid JSON ({err})") from None
        if not isinstance(mapping, dict):
            raise WodE2EError(f"{path}: expected an object of sequence -> cluster, got {type(mapping).__name__}")
        for sequence, entry in mapping.items():
            name = entry.get("scenario_cluster") if isinstance(entry, dict) else entry
            if not isinstance(name, str):
                raise WodE2EError(
                    f"{path}: entry {sequence!r}: expected a cluster name or {{'scenario_cluster': name}}"
                )
            clusters[sequence] = name
    return clusters


def _states(states: Any, names: tuple[str, ...], where: str) -> np.ndarray:
    """Columns of an ``EgoTrajectoryStates`` as float32 (N, len(names)); all must have the same length."""
    columns = [np.asarray(getattr(states, name), dtype=np.float32) for name in names]
    for name, column in zip(names, columns, strict=True):
        if len(column) != len(columns[0]):
            raise WodE2EError(f"{where}.{name}: {len(column)} values, but {names[0]} has {len(columns[0])}")
    return np.stack(columns, axis=1) if columns[0].size else np.zeros((0, len(names)), np.float32)


def _camera(calibration: Any, where: str) -> dict[str, Any]:
    """Schema camera entry: K and distortion from ``intrinsic``, cam_to_ego with OpenCV camera axes."""
    intrinsic = list(calibration.intrinsic)
    if len(intrinsic) != 9:
        raise WodE2EError(
            f"{where}.intrinsic: expected 9 values [f_u, f_v, c_u, c_v, k1, k2, p1, p2, k3], got {len(intrinsic)}"
        )
    if len(calibration.extrinsic.transform) != 16:
        raise WodE2EError(
            f"{where}.extrinsic.transform: expected 16 values, got {len(calibration.extrinsic.transform)}"
        )
    f_u, f_v, c_u, c_v = intrinsic[:4]
    extrinsic = np.asarray(calibration.extrinsic.transform, dtype=np.float64).reshape(4, 4)
    camera_id, native = CAMERAS[calibration.name]
    return {
        "id": camera_id,
        "native_name": native,
        "width": calibration.width,
        "height": calibration.height,
        "K": [[f_u, 0.0, c_u], [0.0, f_v, c_v], [0.0, 0.0, 1.0]],
        "distortion": intrinsic[4:],
        "cam_to_ego": (extrinsic @ OPENCV_TO_WAYMO).tolist(),
    }


def _cameras(message: E2EDFrame, where: str) -> list[tuple[dict[str, Any], bytes]]:
    """(camera entry, JPEG bytes) per image, in camera-name order."""
    calibrations = {c.name: c for c in message.frame.context.camera_calibrations}
    out = []
    for image in sorted(message.frame.images, key=lambda i: i.name):
        field = f"{where}: frame.images[name={image.name}]"
        if image.name not in CAMERAS:
            raise WodE2EError(f"{field}: unknown camera name")
        if image.name not in calibrations:
            raise WodE2EError(f"{field}: no frame.context.camera_calibrations entry for this camera")
        calibration_field = f"{where}: frame.context.camera_calibrations[name={image.name}]"
        out.append((_camera(calibrations[image.name], calibration_field), image.image))
    return out


def _raters(message: E2EDFrame, where: str) -> dict[str, np.ndarray] | None:
    """Rated trajectories NaN-padded to the longest, with scores and true lengths; None when none is rated."""
    rated = [p for p in message.preference_trajectories if _rated(p)]
    if not rated:
        return None
    xys = [_states(p, ("pos_x", "pos_y"), f"{where}: preference_trajectories") for p in rated]
    lengths = np.array([len(xy) for xy in xys], dtype=np.int32)
    trajectories = np.full((len(xys), lengths.max(), 2), np.nan, dtype=np.float32)
    for row, xy in zip(trajectories, xys, strict=True):
        row[: len(xy)] = xy
    scores = np.array([p.preference_score for p in rated], dtype=np.float32)
    return {"trajectories": trajectories, "scores": scores, "lengths": lengths}


def _ego(past: np.ndarray, intent: int) -> dict[str, Any]:
    """Ego state at t0 from the last past state; yaw rate = (v x a) / |v|^2, i.e. curvature times speed."""
    vx, vy, ax, ay = (float(v) for v in past[-1, 2:6])
    speed = float(np.hypot(vx, vy))
    yaw_rate = (vx * ay - vy * ax) / speed**2 if speed >= MIN_SPEED_FOR_YAW_RATE else 0.0
    return {
        "speed": speed,
        "velocity": [vx, vy],
        "acceleration": [ax, ay],
        "yaw_rate": yaw_rate,
        "command": int(INTENTS.get(intent, Command.UNKNOWN)),
        "command_raw": intent,
    }


def _trajectory(xy: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[t, x, y, yaw] rows; WOD-E2E states carry no heading, so yaw is NaN (0 at t0 by definition of the frame)."""
    yaw = np.where(t == 0, 0.0, np.nan)
    return np.column_stack([t, xy, yaw]).astype(np.float32)


class WodE2EAdapter(Adapter):
    """Waymo Open Dataset end-to-end driving (WOD-E2E) TFRecords; see the module docstring for the error policy."""

    name = "wod_e2e"
    version = "1"
    extras = "wod"

    def __init__(
        self, history: int = 0, index_dir: str | None = None, index_workers: int = 1, strict: bool = False
    ) -> None:
        """``history``: attach the K previous frames' front images (``cam_front_prev1..K``, gaps flagged false);
        ``index_dir``: where the per-split record index is cached; ``index_workers``: processes for the indexing
        pass (one shard each at a time); ``strict``: fail on any bad record instead of skipping it."""
        if history < 0:
            raise ValueError(f"history must be >= 0, got {history}")
        self.history = history
        self.index_dir = None if index_dir is None else Path(index_dir)
        self.index_workers = index_workers
        self.strict = strict
        self.skipped: list[dict[str, Any]] = []
        self.frame_gaps: dict[str, list[str]] = {}

    def index(self, split: str, shards: list[Path]) -> list[dict[str, Any]]:
        """Index rows of one split sorted by (sequence, frame); duplicates and bad records go to :attr:`skipped`."""
        cache = None if self.index_dir is None else self.index_dir / f"{split}.index.parquet"
        index = cached_index(shards, _index_columns, INDEX_SCHEMA, cache, self.index_workers)
        rows = sorted(index.table.to_pylist(), key=lambda r: (r["sequence"], r["frame"], r["shard"], r["offset"]))
        skipped = list(index.skipped)
        kept: list[dict[str, Any]] = []
        for row in rows:
            if kept and (kept[-1]["sequence"], kept[-1]["frame"]) == (row["sequence"], row["frame"]):
                where = f"{row['shard']}: record at offset {row['offset']}"
                error = f"{where}: duplicate of frame {row['sequence']}-{row['frame']:03d}, the first copy is kept"
                skipped.append({"shard": row["shard"], "offset": row["offset"], "error": error})
            else:
                kept.append(row)
        if skipped and self.strict:
            raise WodE2EError(f"{len(skipped)} bad records in split {split!r} (strict); first: {skipped[0]['error']}")
        self.skipped.extend(skipped)
        return kept

    def list_logs(self, src: Path) -> list[LogRef]:
        clusters = load_clusters(src)
        logs, self.frame_gaps = [], {}
        for split, shards in sorted(find_shards(src).items()):
            rows = self.index(split, shards)
            held = Counter(str(row["shard"]) for row in rows)
            missing = [f"{path} (missing)" for path in missing_shards(shards)] + thin_shards(shards, held)
            for sequence, group in groupby(rows, key=lambda r: r["sequence"]):
                records = [(r["frame"], r["shard"], r["offset"], r["length"]) for r in group]
                gaps = frame_gaps([frame for frame, *_ in records])
                if gaps:
                    self.frame_gaps[f"{split}/{sequence}"] = gaps
                extra = {"records": records, "cluster": clusters.get(sequence), "missing_shards": missing}
                logs.append(LogRef(sequence, split, str(src), extra))
        return logs

    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        missing = log.extra.get("missing_shards")
        if missing:
            raise WodE2EError(
                f"segment {log.log_id} ({log.split}): its split's shard set is incomplete: {', '.join(missing)}; its "
                "frames are shuffled over every shard, so some are missing: download the file(s) again"
            )
        recent: dict[int, tuple[dict[str, Any], bytes]] = {}
        with RecordReader() as reader:
            for frame_idx, shard, offset, length in log.extra["records"]:
                where = f"{shard}: record at offset {offset}"
                try:
                    message = parse_frame(reader.read(shard, offset, length))
                except WodE2EError as err:
                    raise WodE2EError(f"{where}: {err}") from None
                if split_name(message.frame.context.name) != (log.log_id, frame_idx):
                    raise WodE2EError(f"{where}: holds {message.frame.context.name!r}, not the indexed frame; re-index")
                sample = self._sample(message, log, frame_idx, shard, offset)
                self._attach_history(sample, frame_idx, recent)
                yield sample

    def _sample(self, message: E2EDFrame, log: LogRef, frame_idx: int, shard: str, offset: int) -> dict[str, Any]:
        where = f"{shard}: record at offset {offset}"
        past_states = _states(
            message.past_states, ("pos_x", "pos_y", "vel_x", "vel_y", "accel_x", "accel_y"), f"{where}: past_states"
        )
        if not len(past_states):
            raise WodE2EError(f"{where}: past_states is empty")
        future_xy = _states(message.future_states, ("pos_x", "pos_y"), f"{where}: future_states")
        sample: dict[str, Any] = {"__key__": make_key(log.log_id, f"{frame_idx:03d}")}
        cluster = log.extra.get("cluster")
        sample["past"] = _trajectory(
            past_states[:, :2], STATE_DT * (np.arange(len(past_states)) - len(past_states) + 1)
        )
        if len(future_xy):
            sample["future"] = _trajectory(future_xy, STATE_DT * (np.arange(len(future_xy)) + 1))
        raters = _raters(message, where)
        if raters is not None:
            sample["raters"] = raters
        cameras = _cameras(message, where)
        for camera, jpeg in cameras:
            sample[f"cam_{camera['id']}"] = jpeg
        has = {name: name in sample for name in ("future", "raters", "target_points", "lidar", "boxes")}
        has.update({f"cam_{camera['id']}": True for camera, _ in cameras})
        sample["meta"] = {
            "schema_version": SCHEMA_VERSION,
            "dataset": "wod_e2e",
            "split": log.split,
            "log_id": log.log_id,
            "frame_idx": frame_idx,
            "timestamp_us": frame_idx * FRAME_DT_US,
            "is_synthetic": False,
            "location": None,
            "adapter": self.name,
            "adapter_version": self.version,
            "ego": _ego(past_states, message.intent),
            "vehicle": dict(VEHICLE),
            "cameras": [camera for camera, _ in cameras],
            "has": has,
            "tags": [] if cluster is None else [f"cluster:{cluster}"],
            "extras": {
                "wod_e2e": {
                    "frame_name": message.frame.context.name,
                    "cluster": cluster,
                    "intent": message.intent,
                    "past_velocity": past_states[:, 2:4].tolist(),
                    "past_acceleration": past_states[:, 4:6].tolist(),
                    "record": {"shard": Path(shard).name, "offset": offset},
                }
            },
        }
        return sample

    def _attach_history(
        self, sample: dict[str, Any], frame_idx: int, recent: dict[int, tuple[dict[str, Any], bytes]]
    ) -> None:
        """Front images of frames ``frame_idx - 1 .. - K`` seen earlier in this log; a missing one is flagged false."""
        if not self.history:
            return
        meta = sample["meta"]
        present = []
        for k in range(1, self.history + 1):
            name = f"front_prev{k}"
            entry = recent.get(frame_idx - k)
            present.append(entry is not None)
            meta["has"][f"cam_{name}"] = entry is not None
            if entry is not None:
                camera, jpeg = entry
                sample[f"cam_{name}"] = jpeg
                meta["cameras"].append({**camera, "id": name, "dt": -k * FRAME_DT_US / 1e6})
        meta["extras"]["wod_e2e"]["history"] = {
            "frames": [frame_idx - k for k in range(1, self.history + 1)],
            "present": present,
        }
        front = next((c for c in meta["cameras"] if c["id"] == "front"), None)
        if front is not None:
            recent[frame_idx] = (front, sample["cam_front"])
        for old in [f for f in recent if f < frame_idx - self.history + 1]:
            del recent[old]

    def options(self) -> dict[str, Any]:
        return {"history": self.history}  # index_dir, index_workers and strict never change a sample

    def bad_records(self) -> list[dict[str, Any]]:
        return list(self.skipped)

    def describe(self) -> dict[str, Any]:
        return {
            "dataset": "wod_e2e",
            "frame": "ISO 8855, origin at the rear axle at t0 (native WOD-E2E, nothing flipped)",
            "rates_hz": {"frames": 10.0, "past": 4.0, "future": 4.0},
            "horizons_s": {"past": 3.75, "future": 5.0},
            "cameras": [camera_id for camera_id, _ in CAMERAS.values()],
            "camera_axes": "OpenCV (x right, y down, z forward); Waymo's extrinsic = cam_to_ego @ inv(OPENCV_TO_WAYMO)",
            "history": self.history,
            "vehicle": {**VEHICLE, "note": "nominal Jaguar I-PACE; the dataset does not state its vehicle"},
            "skipped_records": self.skipped,
            "frame_gaps": self.frame_gaps,
        }
