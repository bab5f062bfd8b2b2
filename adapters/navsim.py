"""NAVSIM / OpenScene -> schema v1: one sample per scene token, read from the files NAVSIM's download scripts leave.

``<src>/navsim_logs/<split>/<log>.pkl`` (a plain pickle of per-frame dicts at 2 Hz, read with a restricted
unpickler), ``<src>/sensor_blobs/<split>/<log>/...`` (JPEGs and nuPlan binary PCDs) and, with ``maps``, nuPlan
GeoPackage maps (:mod:`lead_s2r_adapters.navsim_map`). A scene is NAVSIM's window of ``num_history_frames``
frames (the last is the current frame, whose token is the scene token) plus ``num_future_frames``. nuPlan
data is already ISO 8855 with the origin at the rear axle, so nothing is flipped. Each worker loads a log
pickle once and a map once per location. Layout of every field: ``docs/datasets/navsim.md``.
"""

import io
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from lead_s2r.errors import UserError
from lead_s2r.formats import restricted_pickle
from lead_s2r.geometry import rotate, to_global, to_local, wrap_angle
from lead_s2r.registry import Adapter, LogRef
from lead_s2r.schema import SCHEMA_VERSION, BoxClass, Command, make_key
from lead_s2r.scoring.pdm.two_stage import TwoStageGroup, parse_mapping
from lead_s2r_adapters import navsim_map

#: NAVSIM camera -> our camera id.
CAMERAS = {
    "CAM_F0": "front",
    "CAM_L0": "front_left",
    "CAM_L1": "left",
    "CAM_L2": "back_left",
    "CAM_R0": "front_right",
    "CAM_R1": "right",
    "CAM_R2": "back_right",
    "CAM_B0": "back",
}
BOX_CLASSES = {
    "vehicle": BoxClass.VEHICLE,
    "pedestrian": BoxClass.PEDESTRIAN,
    "bicycle": BoxClass.BICYCLE,
    "traffic_cone": BoxClass.TRAFFIC_CONE,
    "barrier": BoxClass.BARRIER,
    "czone_sign": BoxClass.CZONE_SIGN,
    "generic_object": BoxClass.GENERIC_OBJECT,
}
#: ``driving_command`` one-hot order (left, forward, right, unknown).
COMMANDS = (Command.LEFT, Command.STRAIGHT, Command.RIGHT, Command.UNKNOWN)
#: nuPlan's Chrysler Pacifica (``get_pacifica_parameters``).
PACIFICA = {"length": 5.176, "width": 2.297, "wheel_base": 3.089, "rear_axle_to_center": 1.461}
CHECK = "check_tokens"
SYNTHETIC = "synthetic_scene"
#: NAVSIM SceneFilter defaults (navtrain / navtest): 4 history frames including the current one, 10 future frames.
DEFAULT_HISTORY, DEFAULT_FUTURE = 4, 10
#: SceneFilter fields that select v2 synthetic scenes (their union is converted).
SYNTHETIC_TOKEN_FIELDS = (
    "synthetic_scene_tokens",
    "reactive_synthetic_initial_tokens",
    "non_reactive_synthetic_initial_tokens",
)
#: v2 two-stage split folders (``navhard_two_stage``, ...): logs, sensors and synthetic scenes side by side.
TWO_STAGE_LOGS, TWO_STAGE_SENSORS, TWO_STAGE_SYNTHETIC = (
    "openscene_meta_datas",
    "sensor_blobs",
    "synthetic_scene_pickles",
)


class NavsimFormatError(UserError, ValueError):
    """A source file breaks the OpenScene format; the message names the file and the field."""


# --------------------------------------------------------------------------- readers


def load_log(path: Path) -> list[dict[str, Any]]:
    """The frames of an OpenScene log pickle, checked to be a non-empty list of dicts."""
    try:
        with open(path, "rb") as file:
            frames = restricted_pickle.load(file)
    except FileNotFoundError:
        raise
    except Exception as err:
        raise NavsimFormatError(f"{path}: not a readable OpenScene log pickle ({type(err).__name__}: {err})") from None
    if not isinstance(frames, list) or not frames or not all(isinstance(f, dict) for f in frames):
        raise NavsimFormatError(f"{path}: expected a non-empty list of frame dicts, got {type(frames).__name__}")
    return frames


_PCD_TYPES = {"F": "f", "U": "u", "I": "i"}


def read_pcd(path: Path) -> tuple[np.ndarray, list[str]]:
    """Points (N, C) float32 and field names of an ASCII or binary PCD (nuPlan's MergedPointCloud)."""
    data = path.read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    while "DATA" not in header:
        end = data.find(b"\n", pos)
        if end < 0:
            raise NavsimFormatError(f"{path}: PCD header has no DATA line")
        line = data[pos:end].decode("ascii", "replace").strip()
        pos = end + 1
        if line and not line.startswith("#"):
            key, *values = line.split()
            header[key.upper()] = values
    try:
        names = header["FIELDS"]
        counts = [int(c) for c in header.get("COUNT", ["1"] * len(names))]
        kinds = [f"<{_PCD_TYPES[t]}{s}" for t, s in zip(header["TYPE"], header["SIZE"], strict=True)]
        n = int(header["POINTS"][0])
    except (KeyError, ValueError) as err:
        raise NavsimFormatError(f"{path}: bad PCD header field {err}") from None
    dtype = np.dtype([(name, kind, (count,)) for name, kind, count in zip(names, kinds, counts, strict=True)])
    mode = header["DATA"][0].lower()
    if mode == "binary":
        if len(data) - pos < n * dtype.itemsize:
            raise NavsimFormatError(f"{path}: PCD holds fewer bytes than its {n} points need")
        records = np.frombuffer(data, dtype, count=n, offset=pos)
        points = np.concatenate([records[name].reshape(n, -1) for name in names], axis=1)
    elif mode == "ascii":
        points = np.loadtxt(io.BytesIO(data[pos:]), dtype=np.float64, ndmin=2)[:n]
    else:
        raise NavsimFormatError(f"{path}: PCD DATA {mode!r} is not supported (binary or ascii)")
    columns = [name if c == 1 else f"{name}_{j}" for name, c in zip(names, counts, strict=True) for j in range(c)]
    return points.astype(np.float32).reshape(n, len(columns)), columns


_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def jpeg_size(data: bytes, where: str) -> tuple[int, int]:
    """(width, height) from a JPEG's frame header, without decoding the image."""
    i = 2
    while data[:2] == b"\xff\xd8" and i + 9 <= len(data):
        if data[i] != 0xFF:
            break
        marker = data[i + 1]
        if marker == 0xFF or 0xD0 <= marker <= 0xD7 or marker == 0x01:
            i += 1 if marker == 0xFF else 2
            continue
        if marker in _SOF:
            return int.from_bytes(data[i + 7 : i + 9], "big"), int.from_bytes(data[i + 5 : i + 7], "big")
        i += 2 + int.from_bytes(data[i + 2 : i + 4], "big")
    raise NavsimFormatError(f"{where}: not a JPEG with a frame header")


def quaternion_matrix(q: Any) -> np.ndarray:
    """3x3 rotation of a [w, x, y, z] quaternion (normalised first)."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_yaw(q: Any) -> float:
    w, x, y, z = np.asarray(q, np.float64)
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def homogeneous(rotation: Any, translation: Any) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, :3], matrix[:3, 3] = np.asarray(rotation, np.float64), np.asarray(translation, np.float64)
    return matrix


def ego_meta(velocity: list[float], acceleration: list[float], one_hot: np.ndarray, previous: np.ndarray) -> dict:
    """``meta.ego`` from a NAVSIM ego status; the yaw rate comes from the previous past pose ``[t < 0, x, y, yaw]``
    (the status has none), 0 without one. A command that is not one-hot is UNKNOWN's raw code 3."""
    raw = int(np.argmax(one_hot)) if one_hot.sum() == 1 else 3
    yaw_rate = float(wrap_angle(0.0 - previous[3]) / (0.0 - previous[0])) if previous[0] < 0 else 0.0
    return {
        "speed": math.hypot(*velocity),
        "velocity": list(velocity),
        "acceleration": list(acceleration),
        "yaw_rate": yaw_rate,
        "command": int(COMMANDS[raw]),
        "command_raw": raw,
    }


def sample_meta(
    adapter: Any, split: str, log_id: str, frame_idx: int, timestamp_us: int, is_synthetic: bool, extras: dict
) -> dict[str, Any]:
    """The ``meta`` entries every NAVSIM sample shares, logged or synthetic."""
    return {
        "schema_version": SCHEMA_VERSION,
        "dataset": "navsim",
        "split": split,
        "log_id": log_id,
        "frame_idx": frame_idx,
        "timestamp_us": timestamp_us,
        "is_synthetic": is_synthetic,
        "location": extras["map_name"],
        "adapter": adapter.name,
        "adapter_version": adapter.version,
        "vehicle": dict(PACIFICA),
        "extras": {"navsim": extras},
    }


def read_camera(
    cam: dict, native: str, cam_id: str, sensors: Path, lidar2ego: np.ndarray, where: str
) -> tuple[bytes, dict[str, Any]]:
    """One camera's JPEG bytes as stored and its ``meta.cameras`` entry (OpenScene calibrates cameras to the LiDAR,
    so ``cam_to_ego`` goes through ``lidar2ego``)."""
    path = sensors / str(_field(cam, "data_path", where))
    if not path.is_file():
        raise FileNotFoundError(f"{where}: sensor blob {path} is missing")
    data = path.read_bytes()
    width, height = jpeg_size(data, str(path))
    sensor2lidar = homogeneous(
        _field(cam, "sensor2lidar_rotation", where), _field(cam, "sensor2lidar_translation", where)
    )
    entry = {
        "id": cam_id,
        "native_name": native,
        "width": width,
        "height": height,
        "K": np.asarray(_field(cam, "cam_intrinsic", where), np.float64).tolist(),
        "distortion": np.asarray(_field(cam, "distortion", where), np.float64).tolist(),
        "cam_to_ego": (lidar2ego @ sensor2lidar).tolist(),
    }
    return data, entry


# --------------------------------------------------------------------------- scene filters


@dataclass(frozen=True)
class SceneFilter:
    """The parts of NAVSIM's SceneFilter a conversion uses; None = not constrained by the filter."""

    name: str
    tokens: frozenset[str] | None = None
    log_names: frozenset[str] | None = None
    num_history_frames: int | None = None
    num_future_frames: int | None = None
    frame_interval: int | None = None
    has_route: bool = True
    include_synthetic: bool = False
    synthetic_tokens: frozenset[str] | None = None  # v2 synthetic (stage-2) scenes to convert; None = all


def read_scene_filter(path: Path) -> SceneFilter:
    """A NAVSIM scene-filter yaml (``tokens``, ``log_names``, frame counts) or a text file of one token a line."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"scene filter {path} does not exist")
    if path.suffix not in (".yaml", ".yml"):
        lines = [line.strip() for line in path.read_text().splitlines()]
        return SceneFilter(path.stem, tokens=frozenset(t for t in lines if t and not t.startswith("#")))
    config = yaml.safe_load(path.read_text()) or {}
    if not isinstance(config, dict):
        raise NavsimFormatError(f"{path}: a scene filter must be a mapping")

    def optional(name: str, kind: type) -> Any:
        value = config.get(name)
        if value is not None and not isinstance(value, kind):
            raise NavsimFormatError(f"{path}: field {name!r} must be {kind.__name__}, got {value!r}")
        return value

    tokens, logs = optional("tokens", list), optional("log_names", list)
    history, future = optional("num_history_frames", int), optional("num_future_frames", int)
    interval = optional("frame_interval", int)
    synthetic = [optional(name, list) for name in SYNTHETIC_TOKEN_FIELDS]
    if interval is None:  # NAVSIM's SceneFilter: no frame_interval = back-to-back scenes of its own num_frames
        interval = (history or DEFAULT_HISTORY) + (future or DEFAULT_FUTURE)
    return SceneFilter(
        name=path.stem,
        tokens=None if tokens is None else frozenset(map(str, tokens)),
        log_names=None if logs is None else frozenset(map(str, logs)),
        num_history_frames=history,
        num_future_frames=future,
        frame_interval=interval,
        has_route=bool(config.get("has_route", True)),
        include_synthetic=bool(config.get("include_synthetic_scenes", False)),
        synthetic_tokens=None
        if all(v is None for v in synthetic)
        else frozenset(str(t) for v in synthetic for t in v or []),
    )


def read_two_stage_mapping(path: Path) -> list[TwoStageGroup]:
    """``reactive_all_mapping`` of a NAVSIM v2 train/test-split yaml (e.g. ``navhard_two_stage.yaml``)."""
    if not path.is_file():
        raise FileNotFoundError(f"two-stage mapping {path} does not exist")
    config = yaml.safe_load(path.read_text()) or {}
    raw = config.get("reactive_all_mapping") if isinstance(config, dict) else None
    if not isinstance(raw, list):
        raise NavsimFormatError(f"{path}: field 'reactive_all_mapping' must be a list of [orig, prev, pairs] entries")
    try:
        return parse_mapping(raw)
    except ValueError as err:
        raise NavsimFormatError(f"{path}: {err}") from None


def two_stage_roles(groups: list[TwoStageGroup]) -> dict[str, dict[str, Any]]:
    """token -> ``stage`` (1 or 2), ``two_stage_role`` and the token's ``two_stage_group`` [orig, prev, pairs]."""
    roles: dict[str, dict[str, Any]] = {}
    for group in groups:
        raw = [group.original, group.previous, [list(pair) for pair in group.pairs]]
        roles[group.original] = {"stage": 1, "two_stage_role": "original", "two_stage_group": raw}
        roles[group.previous] = {"stage": 1, "two_stage_role": "previous", "two_stage_group": raw}
        for now, before in group.pairs:
            roles[now] = {"stage": 2, "two_stage_role": "now", "two_stage_group": raw}
            roles[before] = {"stage": 2, "two_stage_role": "previous", "two_stage_group": raw}
    return roles


# --------------------------------------------------------------------------- the adapter


def _field(frame: dict[str, Any], name: str, where: str) -> Any:
    if name not in frame:
        raise NavsimFormatError(f"{where}: field {name!r} is missing")
    return frame[name]


class NavsimAdapter(Adapter):
    """OpenScene logs (+ sensor blobs, + nuPlan maps with ``maps``) -> one schema v1 sample per scene token.

    ``split`` picks a folder of ``navsim_logs`` (``trainval``, ``test``, ``mini``; default all);
    ``scene_filter`` a NAVSIM scene-filter yaml or token list (its frame counts apply unless given here);
    ``maps`` the nuPlan maps root, which adds ``scoring`` and ``bev_semantic``;
    ``two_stage_mapping`` a NAVSIM v2 train/test-split yaml with ``reactive_all_mapping`` (navhard two-stage): every
    sample then records its stage and group in ``meta.extras.navsim`` and info.json keeps the whole mapping.
    A split folder laid out as NAVSIM v2's two-stage splits (``<src>/<split>/openscene_meta_datas``, ...) is read
    with its synthetic scenes (:mod:`lead_s2r_adapters.navsim_synthetic`).
    """

    name = "navsim"
    version = "1.1.0"
    extras = "navsim"

    def __init__(
        self,
        split: str | None = None,
        scene_filter: str | None = None,
        maps: str | None = None,
        num_history_frames: int | None = None,
        num_future_frames: int | None = None,
        frame_interval: int | None = None,
        map_radius: float = 100.0,
        two_stage_mapping: str | None = None,
    ) -> None:
        self.split = split
        self.filter = read_scene_filter(Path(scene_filter)) if scene_filter else None
        self.filter_path = scene_filter
        self.maps = Path(maps) if maps else None
        given = self.filter or SceneFilter("all")
        self.history = num_history_frames or given.num_history_frames or DEFAULT_HISTORY
        self.future = num_future_frames or given.num_future_frames or DEFAULT_FUTURE
        self.interval = frame_interval or given.frame_interval or 1
        self.has_route = given.has_route
        self.map_radius = map_radius
        if self.history < 2 or self.future < 1 or self.interval < 1:
            raise ValueError("need num_history_frames >= 2, num_future_frames >= 1 and frame_interval >= 1")
        self.mapping = read_two_stage_mapping(Path(two_stage_mapping)) if two_stage_mapping else None
        self._roles = two_stage_roles(self.mapping or [])

    def options(self) -> dict[str, Any]:
        return {
            "split": self.split,
            "scene_filter": self.filter_path,
            "maps": None if self.maps is None else str(self.maps),
            "num_history_frames": self.history,
            "num_future_frames": self.future,
            "frame_interval": self.interval,
            "map_radius": self.map_radius,
        }

    # ----------------------------------------------------------------------- logs

    def list_logs(self, src: Path) -> list[LogRef]:
        two_stage = Path(src) / (self.split or "") / TWO_STAGE_LOGS
        if self.split and two_stage.is_dir():
            return self._list_two_stage(Path(src), self.split)
        root = Path(src) / "navsim_logs"
        if not root.is_dir():
            raise FileNotFoundError(f"{root} does not exist: src must be an OpenScene root with navsim_logs/")
        splits = [self.split] if self.split else sorted(p.name for p in root.iterdir() if p.is_dir())
        refs = []
        for split in splits:
            if not (root / split).is_dir():
                raise FileNotFoundError(f"split folder {root / split} does not exist")
            refs += self._log_refs(root / split, Path(src) / "sensor_blobs" / split, split)
        return refs + self._filter_check(refs, ",".join(splits), [])

    def _log_refs(self, logs: Path, sensors: Path, split: str) -> list[LogRef]:
        refs = []
        for path in sorted(logs.glob("*.pkl")):
            if self.filter and self.filter.log_names is not None and path.stem not in self.filter.log_names:
                continue
            refs.append(LogRef(path.stem, split, str(path), {"sensors": str(sensors)}))
        return refs

    def _list_two_stage(self, src: Path, split: str) -> list[LogRef]:
        """A v2 two-stage split folder: its logs (stage 1), then one work item per synthetic scene (stage 2)."""
        folder = src / split
        refs = self._log_refs(folder / TWO_STAGE_LOGS, folder / TWO_STAGE_SENSORS, split)
        wanted = self.filter.synthetic_tokens if self.filter else None
        missing: list[str] = []
        if self.filter is None or self.filter.include_synthetic or self.mapping is not None:
            scenes = folder / TWO_STAGE_SYNTHETIC
            stems = {path.stem: path for path in sorted(scenes.glob("*.pkl"))}
            tokens = sorted(stems if wanted is None else wanted)
            missing = [token for token in tokens if token not in stems]
            extra = {"sensors": str(folder / TWO_STAGE_SENSORS), "logs": str(folder / TWO_STAGE_LOGS), SYNTHETIC: True}
            refs += [LogRef(token, split, str(stems[token]), extra) for token in tokens if token in stems]
        original = [ref for ref in refs if SYNTHETIC not in ref.extra]
        return refs + self._filter_check(original, split, missing)

    def _filter_check(self, refs: list[LogRef], splits: str, missing_synthetic: list[str]) -> list[LogRef]:
        if self.filter is None or (
            self.filter.tokens is None and self.filter.log_names is None and not missing_synthetic
        ):
            return []
        found = {ref.log_id for ref in refs}
        missing = sorted((self.filter.log_names or set()) - found)
        check = {CHECK: [ref.path for ref in refs], "missing_logs": missing, "missing_synthetic": missing_synthetic}
        return [LogRef(f"scene-filter-{self.filter.name}", splits, str(self.filter_path), check)]

    def two_stage_extras(self, token: str) -> dict[str, Any]:
        """``meta.extras.navsim`` fields of a token of the two-stage mapping: its stage (1 or 2), role and group."""
        return dict(self._roles.get(token, {}))

    def windows(self, frames: list[dict[str, Any]], where: str) -> Iterator[tuple[int, int]]:
        """(first, current) frame indices of NAVSIM's scenes in a log, before the token filter."""
        size = self.history + self.future
        for start in range(0, len(frames) - size + 1, self.interval):
            current = start + self.history - 1
            if self.has_route and not _field(frames[current], "roadblock_ids", f"{where} frame {current}"):
                continue
            yield start, current

    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        if CHECK in log.extra:
            yield from self._check_filter(log)
            return
        if SYNTHETIC in log.extra:
            from lead_s2r_adapters import navsim_synthetic  # it builds on this module

            yield from navsim_synthetic.iter_samples(self, log)
            return
        path = Path(log.path)
        frames = load_log(path)
        scene = _LogContext(self, log, frames)
        for start, current in self.windows(frames, str(path)):
            token = str(_field(frames[current], "token", f"{path} frame {current}"))
            if self.filter is None or self.filter.tokens is None or token in self.filter.tokens:
                yield scene.sample(start, current)

    def _check_filter(self, log: LogRef) -> Iterator[dict[str, Any]]:
        """Report scene-filter tokens (and log names) that no log on disk provides; yields no samples."""
        assert self.filter is not None
        found: set[str] = set()
        unreadable = []
        for path in log.extra[CHECK]:
            try:
                frames = load_log(Path(path))
                found.update(str(frames[current].get("token")) for _, current in self.windows(frames, path))
            except (OSError, ValueError):  # its own conversion reports why
                unreadable.append(Path(path).stem)
        missing = sorted((self.filter.tokens or set()) - found)
        problems = []
        if log.extra["missing_logs"]:
            problems.append(f"log names with no pickle: {', '.join(log.extra['missing_logs'][:20])}")
        if log.extra.get("missing_synthetic"):
            names = log.extra["missing_synthetic"]
            problems.append(f"{len(names)} synthetic scene tokens with no pickle: {', '.join(names[:20])}")
        if missing:
            problems.append(
                f"{len(missing)} tokens in no readable log with a full {self.history}+{self.future}-frame window: "
                f"{', '.join(missing[:20])}{' ...' if len(missing) > 20 else ''}"
                + (f" (unreadable logs: {', '.join(unreadable)})" if unreadable else "")
            )
        if problems:
            raise LookupError(f"scene filter {log.path}: " + "; ".join(problems))
        yield from ()

    def describe(self) -> dict[str, Any]:
        return {
            "dataset": "navsim",
            "rate_hz": 2.0,
            "num_history_frames": self.history,
            "num_future_frames": self.future,
            "horizon_s": self.future * 0.5,
            "cameras": list(CAMERAS.values()),
            "scene_filter": self.filter.name if self.filter else None,
            "maps": self.maps is not None,
            "bev": navsim_map.BEV_META if self.maps is not None else None,
            "two_stage": None
            if self.mapping is None
            else {
                "stage_one_tokens": [t for g in self.mapping for t in (g.original, g.previous)],
                "stage_two_tokens": [t for g in self.mapping for pair in g.pairs for t in pair],
                "reactive_all_mapping": [[g.original, g.previous, [list(p) for p in g.pairs]] for g in self.mapping],
            },
        }


class _LogContext:
    """One loaded log: global ego poses once, then a sample per scene."""

    def __init__(self, adapter: NavsimAdapter, log: LogRef, frames: list[dict[str, Any]]) -> None:
        self.adapter, self.log, self.frames = adapter, log, frames
        self.path = Path(log.path)
        self.sensors = Path(log.extra["sensors"])
        poses, stamps = [], []
        for i, frame in enumerate(frames):
            where = self.where(i)
            translation = np.asarray(_field(frame, "ego2global_translation", where), np.float64)
            yaw = quaternion_yaw(_field(frame, "ego2global_rotation", where))
            poses.append([translation[0], translation[1], yaw])
            stamps.append(int(_field(frame, "timestamp", where)))
        self.poses = np.array(poses)
        self._annotations: dict[int, dict[str, Any]] = {}
        self.stamps = np.array(stamps, np.int64)
        if (np.diff(self.stamps) <= 0).any():
            raise NavsimFormatError(f"{self.path}: field 'timestamp' is not strictly increasing")

    def where(self, index: int) -> str:
        return f"{self.path} frame {index}"

    def sample(self, start: int, current: int) -> dict[str, Any]:
        adapter, frame, where = self.adapter, self.frames[current], self.where(current)
        origin = self.poses[current]
        index = np.arange(start, current + adapter.future + 1)
        t = ((self.stamps[index] - self.stamps[current]) / 1e6).astype(np.float32)
        local = to_local(self.poses[index], origin)
        trajectory = np.column_stack([t, local]).astype(np.float32)
        lidar2ego = homogeneous(
            quaternion_matrix(_field(frame, "lidar2ego_rotation", where)), _field(frame, "lidar2ego_translation", where)
        )
        token = str(_field(frame, "token", where))
        location = str(_field(frame, "map_location", where))
        sample: dict[str, Any] = {
            "__key__": make_key(self.log.log_id, token),
            "past": trajectory[: adapter.history],
            "future": trajectory[adapter.history :],
        }
        cameras = self.cameras(frame, where, lidar2ego, sample)
        points, columns = read_pcd(self.sensors / str(_field(frame, "lidar_path", where)))
        points[:, :3] = (points[:, :3].astype(np.float64) @ lidar2ego[:3, :3].T + lidar2ego[:3, 3]).astype(np.float32)
        sample["lidar"] = points
        extras: dict[str, Any] = {
            "scene_token": token,
            "initial_token": str(self.frames[start].get("token")),
            "log_name": str(frame.get("log_name", self.log.log_id)),
            "map_location": location,
            "map_name": navsim_map.resolve_location(location),
            "data_split": self.log.split,
            "roadblock_ids": [str(r) for r in _field(frame, "roadblock_ids", where)],
            "traffic_lights": [[int(lc), bool(red)] for lc, red in _field(frame, "traffic_lights", where)],
        } | adapter.two_stage_extras(token)
        if "anns" in frame:
            now = self.annotations(current)
            boxes = np.column_stack([now["boxes"], now["velocity"], now["classes"]]).astype(np.float32).reshape(-1, 10)
            boxes[:, 6] = wrap_angle(boxes[:, 6])
            sample["boxes"] = boxes
            sample["agents_future"] = self.agents_future(current, now)
            extras.update(track_tokens=now["tracks"], box_names=now["names"])
        bev = None
        if adapter.maps is not None:
            sample["scoring"] = self.scoring(current, extras["roadblock_ids"], extras["map_name"])
            sample["bev_semantic"] = navsim_map.render_bev(sample["scoring"], sample.get("boxes", np.zeros((0, 10))))
            bev = navsim_map.BEV_META
        sample["meta"] = self.meta(current, where, trajectory, cameras, columns, extras, sample, bev)
        return sample

    def meta(
        self,
        current: int,
        where: str,
        trajectory: np.ndarray,
        cameras: list[dict[str, Any]],
        columns: list[str],
        extras: dict[str, Any],
        sample: dict[str, Any],
        bev: dict[str, Any] | None,
    ) -> dict[str, Any]:
        frame, adapter = self.frames[current], self.adapter
        state = [float(v) for v in _field(frame, "ego_dynamic_state", where)]
        if len(state) != 4 or not all(math.isfinite(v) for v in state):
            raise NavsimFormatError(f"{where}: field 'ego_dynamic_state' must be 4 finite numbers, got {state!r}")
        one_hot = np.asarray(_field(frame, "driving_command", where)).ravel()
        if one_hot.shape != (4,):
            raise NavsimFormatError(f"{where}: field 'driving_command' must be a (4,) one-hot, got {one_hot!r}")
        previous = trajectory[adapter.history - 2]  # [t < 0, x, y, yaw] relative to the current pose
        split = adapter.filter.name if adapter.filter else self.log.split
        meta = sample_meta(adapter, split, self.log.log_id, current, int(self.stamps[current]), False, extras)
        meta |= {
            "ego": ego_meta(state[:2], state[2:], one_hot, previous),
            "cameras": cameras,
            "lidar_columns": columns,
            "has": {name: True for name in sample if name not in ("__key__", "meta")},
        }
        if bev is not None:
            meta["bev"] = bev
        return meta

    def cameras(self, frame: dict, where: str, lidar2ego: np.ndarray, sample: dict) -> list[dict[str, Any]]:
        cameras = []
        for native, cam_id in CAMERAS.items():
            cam = _field(_field(frame, "cams", where), native, where)
            sample[f"cam_{cam_id}"], entry = read_camera(
                cam, native, cam_id, self.sensors, lidar2ego, f"{where} cams.{native}"
            )
            cameras.append(entry)
        return cameras

    def annotations(self, index: int) -> dict[str, Any]:
        """A frame's ``anns`` as arrays, with classes mapped; boxes (N, 7) in that frame's ego frame. Cached:
        with a stride of 1 every frame is a future frame of up to ``num_future_frames`` scenes."""
        if index not in self._annotations:
            self._annotations[index] = self._read_annotations(index)
        return self._annotations[index]

    def _read_annotations(self, index: int) -> dict[str, Any]:
        where = f"{self.where(index)} anns"
        anns = _field(self.frames[index], "anns", self.where(index))
        boxes = np.asarray(_field(anns, "gt_boxes", where), np.float64).reshape(-1, 7)
        names = [str(n) for n in _field(anns, "gt_names", where)]
        velocity = np.asarray(_field(anns, "gt_velocity_3d", where), np.float64).reshape(-1, 3)
        tracks = [str(t) for t in _field(anns, "track_tokens", where)]
        if not len(boxes) == len(names) == len(velocity) == len(tracks):
            raise NavsimFormatError(f"{where}: gt_boxes, gt_names, gt_velocity_3d and track_tokens differ in length")
        unknown = sorted(set(names) - set(BOX_CLASSES))
        if unknown:
            raise NavsimFormatError(f"{where}: field 'gt_names' has unknown classes {unknown}")
        frame = self.frames[index]
        rotation = quaternion_matrix(_field(frame, "lidar2ego_rotation", self.where(index)))
        velocity = np.nan_to_num(velocity) @ rotation.T  # OpenScene rotates velocities into the lidar frame
        classes = np.array([BOX_CLASSES[n] for n in names], np.float64)
        return {
            "boxes": boxes,
            "names": names,
            "velocity": velocity[:, :2],
            "tracks": tracks,
            "classes": classes,
            "global_poses": to_global(boxes[:, [0, 1, 6]], self.poses[index]),  # for the scenes it is a future of
        }

    def agents_future(self, current: int, now: dict[str, Any]) -> dict[str, np.ndarray]:
        """Future poses of every track seen from ``current`` on, in the current ego frame: the boxes' tracks
        first (row i = box i), then tracks that appear later; NaN and ``valid`` False where unseen."""
        horizon = self.adapter.future
        index = np.arange(current + 1, current + 1 + horizon)
        steps = [self.annotations(i) for i in index]
        order = {token: i for i, token in enumerate(now["tracks"])}
        size = {t: box[3:6] for t, box in zip(now["tracks"], now["boxes"], strict=True)}
        classes = {t: int(label) for t, label in zip(now["tracks"], now["classes"], strict=True)}
        rows = []
        for anns in steps:
            for i, token in enumerate(anns["tracks"]):
                if token not in order:
                    order[token] = len(order)
                    size[token], classes[token] = anns["boxes"][i, 3:6], int(anns["classes"][i])
                rows.append(order[token])
        # every future box of every step in one frame change: (B,) step of each box, its pose and velocity
        step = np.repeat(np.arange(horizon), [len(anns["tracks"]) for anns in steps])
        origin = self.poses[current]
        poses = to_local(np.concatenate([anns["global_poses"] for anns in steps]), origin)
        velocity = rotate(np.concatenate([anns["velocity"] for anns in steps]), self.poses[index[step], 2] - origin[2])
        count = len(order)
        out_poses = np.full((count, horizon, 3), np.nan, np.float32)
        out_velocity = np.full((count, horizon, 2), np.nan, np.float32)
        valid = np.zeros((count, horizon), bool)
        rows = np.array(rows, np.int64)
        out_poses[rows, step], out_velocity[rows, step], valid[rows, step] = poses, velocity, True
        ordered = sorted(order, key=order.get)
        return {
            "t": ((self.stamps[index] - self.stamps[current]) / 1e6).astype(np.float32),
            "poses": out_poses,
            "velocity": out_velocity,
            "valid": valid,
            "size": np.array([size[t] for t in ordered], np.float32).reshape(count, 3),
            "class": np.array([classes[t] for t in ordered], np.int8),
            "num_boxes": np.array(len(now["tracks"]), np.int64),
        }

    def scoring(self, current: int, roadblocks: list[str], map_name: str) -> dict[str, np.ndarray]:
        adapter = self.adapter
        assert adapter.maps is not None
        nuplan_map = navsim_map.load_map(adapter.maps, map_name)
        index = range(current, current + adapter.future + 1)
        red = [
            [int(lc) for lc, is_red in _field(self.frames[i], "traffic_lights", self.where(i)) if is_red] for i in index
        ]
        times = (self.stamps[list(index)] - self.stamps[current]) / 1e6
        context = navsim_map.scoring_context(
            nuplan_map, self.poses[current], adapter.map_radius, roadblocks, red, times
        )
        context["ego_past"] = self.ego_past(current)
        return context

    def ego_past(self, current: int) -> np.ndarray:
        """(P, 8) float64 of the history frames up to and including ``current``: t, x, y, heading in the current
        ego frame, then ``ego_dynamic_state`` (vx, vy, ax, ay, body frame), the logged past EPDMS's HC reads."""
        index = np.arange(current - self.adapter.history + 1, current + 1)
        dynamics = []
        for i in index:
            state = np.asarray(_field(self.frames[i], "ego_dynamic_state", self.where(i)), np.float64).ravel()
            if state.shape != (4,) or not np.isfinite(state).all():
                raise NavsimFormatError(f"{self.where(i)}: field 'ego_dynamic_state' must be 4 finite numbers")
            dynamics.append(state)
        t = (self.stamps[index] - self.stamps[current]) / 1e6
        return np.column_stack([t, to_local(self.poses[index], self.poses[current]), np.array(dynamics)])
