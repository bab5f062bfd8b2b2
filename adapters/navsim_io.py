"""Readers of NAVSIM / OpenScene files apart from the scene logic: log pickles, nuPlan PCDs, JPEG frame headers,
quaternions and the camera calibration entries, each failing with the file and field it cannot read."""

import io
import math
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.errors import UserError
from lead_s2r.formats import restricted_pickle
from lead_s2r.geometry import homogeneous, quaternion_matrix, wrap_angle
from lead_s2r.image_headers import jpeg_size
from lead_s2r.schema import BoxClass

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
#: OpenScene's box class names, in the order of nuPlan's ``TrackedObjectType`` values (EGO = 7 never appears among
#: detections); each is the name of its :class:`~lead_s2r.schema.BoxClass` in lower case.
OBJECT_TYPES = ("vehicle", "pedestrian", "bicycle", "traffic_cone", "barrier", "czone_sign", "generic_object")
BOX_CLASSES = {name: BoxClass[name.upper()] for name in OBJECT_TYPES}


class NavsimFormatError(UserError, ValueError):
    """A source file breaks the OpenScene format; the message names the file and the field."""


def load_pickle(path: Path, what: str, records: Collection[tuple[str, str]] = ()) -> Any:
    """One pickle read with the restricted unpickler (``records``: the foreign classes it may hold); a damaged one is
    an error naming the file and ``what`` it should be."""
    try:
        with open(path, "rb") as file:
            return restricted_pickle.load(file, records)
    except FileNotFoundError:
        raise
    except (OSError, *restricted_pickle.DAMAGED) as err:
        raise NavsimFormatError(f"{path}: not a readable {what} ({type(err).__name__}: {err})") from None


def load_log(path: Path) -> list[dict[str, Any]]:
    """The frames of an OpenScene log pickle, checked to be a non-empty list of dicts."""
    frames = load_pickle(path, "OpenScene log pickle")
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


def quaternion_yaw(q: Any) -> float:
    """Heading (rotation about z) of a [w, x, y, z] quaternion."""
    w, x, y, z = np.asarray(q, np.float64)
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def required(frame: dict[str, Any], name: str, where: str, kind: type | None = None) -> Any:
    """``frame[name]``, or an error naming ``where`` and the field when it is missing or, given ``kind``, of another
    type (a name or path that is not text would otherwise be read as one: ``True`` as a map location)."""
    if name not in frame:
        raise NavsimFormatError(f"{where}: field {name!r} is missing")
    value = frame[name]
    if kind is not None and not isinstance(value, kind):
        raise NavsimFormatError(f"{where}: field {name!r} is {type(value).__name__}, not {kind.__name__}")
    return value


def read_camera(
    cam: dict, native: str, cam_id: str, sensors: Path, lidar2ego: np.ndarray, where: str
) -> tuple[bytes, dict[str, Any]]:
    """One camera's JPEG bytes as stored and its ``meta.cameras`` entry (OpenScene calibrates cameras to the LiDAR,
    so ``cam_to_ego`` goes through ``lidar2ego``)."""
    path = sensors / required(cam, "data_path", where, str)
    if not path.is_file():
        raise FileNotFoundError(f"{where}: sensor blob {path} is missing")
    data = path.read_bytes()
    size = jpeg_size(data)  # from the frame header, without decoding the image
    if size is None:
        raise NavsimFormatError(f"{path}: not a JPEG with a frame header")
    width, height = size
    sensor2lidar = homogeneous(
        required(cam, "sensor2lidar_rotation", where), required(cam, "sensor2lidar_translation", where)
    )
    return data, {
        "id": cam_id,
        "native_name": native,
        "width": width,
        "height": height,
        "K": np.asarray(required(cam, "cam_intrinsic", where), np.float64).tolist(),
        "distortion": np.asarray(required(cam, "distortion", where), np.float64).tolist(),
        "cam_to_ego": (lidar2ego @ sensor2lidar).tolist(),
    }


def lidar2ego(frame: dict[str, Any], where: str) -> np.ndarray:
    """A log frame's 4x4 lidar-to-ego transform, from its ``lidar2ego_rotation`` quaternion and translation."""
    rotation = quaternion_matrix(required(frame, "lidar2ego_rotation", where))
    return homogeneous(rotation, required(frame, "lidar2ego_translation", where))


#: Annotation field names: (boxes, class names, 3-D velocities, track tokens) in a log frame's ``anns`` and in a
#: synthetic scene frame's ``annotations``.
LOG_ANNOTATIONS = ("gt_boxes", "gt_names", "gt_velocity_3d", "track_tokens")
SCENE_ANNOTATIONS = ("boxes", "names", "velocity_3d", "track_tokens")


def read_annotations(
    anns: dict[str, Any], fields: tuple[str, str, str, str], lidar2ego: np.ndarray, where: str
) -> dict[str, Any]:
    """Boxes (N, 7), class ``names``, velocities (N, 2) in the ego frame, track tokens and
    :class:`~lead_s2r.schema.BoxClass` ids (N,) of one frame's annotations, checked to agree in length and class,
    and ``rows``, the boxes as the schema's ``boxes`` field. OpenScene rotates velocities into the lidar frame
    (``lidar2ego`` turns them back) and writes NaN for one it does not know: a box with NaN in x or y keeps NaN
    (unknown, as the schema says, never 0 m/s); a NaN z alone is 0, as the schema keeps only x and y."""
    boxes_field, names_field, velocity_field, tracks_field = fields
    boxes = np.asarray(required(anns, boxes_field, where), np.float64).reshape(-1, 7)
    names = [str(n) for n in required(anns, names_field, where)]
    velocity = np.asarray(required(anns, velocity_field, where), np.float64).reshape(-1, 3)
    tracks = [str(t) for t in required(anns, tracks_field, where)]
    if not len(boxes) == len(names) == len(velocity) == len(tracks):
        raise NavsimFormatError(f"{where}: {', '.join(fields[:3])} and {tracks_field} differ in length")
    unknown = sorted(set(names) - set(BOX_CLASSES))
    if unknown:
        raise NavsimFormatError(f"{where}: field {names_field!r} has unknown classes {unknown}")
    if np.isinf(velocity).any():
        raise NavsimFormatError(f"{where}: field {velocity_field!r} holds infinite values")
    classes = np.array([BOX_CLASSES[n] for n in names], np.float64)
    unknown = np.isnan(velocity[:, :2]).any(axis=1)
    velocity = np.nan_to_num(velocity)
    velocity[unknown] = np.nan
    velocity = (velocity @ lidar2ego[:3, :3].T)[:, :2]
    rows = np.column_stack([boxes, velocity, classes]).astype(np.float32).reshape(-1, 10)
    rows[:, 6] = wrap_angle(rows[:, 6])
    return {"boxes": boxes, "rows": rows, "names": names, "velocity": velocity, "tracks": tracks, "classes": classes}
