"""py123d (123D) Arrow logs read with pyarrow alone: files, schema metadata, the sync index and payload codecs.

A 123D log is a folder ``<root>/logs/<split>/<log_name>/`` of Arrow IPC *files* (not Parquet), one per modality
(``ego_state_se3.arrow``, ``camera.pcam_f0.arrow``, ``lidar.lidar_top.arrow``, ...), plus ``sync.arrow``: one row
per iteration with ``sync.timestamp_us`` and, per modality key, the row index into that modality's file (null where
the modality has no observation). Columns are prefixed with the modality key; each file's static metadata (log
identity, vehicle, calibration, label enum) is msgpack in the Arrow schema metadata under ``b"metadata"``, with
numpy arrays packed as ``{"__ndarray__": True, "dtype", "shape", "data"}`` maps.

We read this layout directly (pinned to py123d 0.7's schema by the tests, which write logs with py123d's own
``ArrowLogWriter``) rather than through py123d's reader API, which imports Ray and OpenCV's GUI build; the
adapter then needs only pyarrow, msgpack and, for LAZ-coded LiDAR, laspy.
"""

import importlib.util
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lead_s2r.errors import UserError
from lead_s2r_adapters.laz_decoder import LazDecodeError, decode_every
from lead_s2r_adapters.py123d_frames import MAX_COORDINATE

METADATA_KEY = b"metadata"
SYNC_FILE = "sync.arrow"
EGO_KEY = "ego_state_se3"
BOX_KEY = "box_detections_se3"
LIGHT_KEY = "traffic_light_detections"
ROUTE_KEY = "route_position"
INSTALL = "pip install 'lead-s2r[py123d]'"


class Py123dFormatError(UserError, ValueError):
    """A 123D log file is unreadable or lacks a field; the message names the file and the field."""

    def __init__(self, path: Path | str, problem: str, field_name: str | None = None) -> None:
        where = f"{path}" if field_name is None else f"{path}, field {field_name!r}"
        super().__init__(f"{where}: {problem}")


def _msgpack() -> Any:
    try:
        import msgpack
    except ImportError:
        raise UserError(f"reading 123D logs needs msgpack: {INSTALL}") from None
    return msgpack


def _ndarray_hook(obj: dict) -> Any:
    if obj.get(b"__ndarray__") or obj.get("__ndarray__"):
        get = {k.decode() if isinstance(k, bytes) else k: v for k, v in obj.items()}
        return np.frombuffer(get["data"], dtype=np.dtype(get["dtype"])).reshape(get["shape"])
    return obj


def unpack(blob: bytes, path: Path, field_name: str) -> dict[str, Any]:
    """py123d's msgpack map (schema metadata, a map object's fields) with its numpy arrays restored; a damaged blob
    is a :class:`Py123dFormatError` naming ``field_name``."""
    msgpack = _msgpack()
    try:
        value = msgpack.unpackb(blob, raw=False, strict_map_key=False, object_hook=_ndarray_hook)
    except (msgpack.exceptions.UnpackException, ValueError, TypeError, KeyError) as err:
        # UnpackException: cut or malformed msgpack (ValueError: bad UTF-8, extra data); TypeError: an unhashable
        # map key or dtype; KeyError / ValueError: an array map without its data or of the wrong size
        raise Py123dFormatError(path, f"not py123d msgpack ({type(err).__name__}: {err})", field_name) from None
    if not isinstance(value, dict):
        raise Py123dFormatError(path, f"expected a msgpack map, got {type(value).__name__}", field_name)
    return value


def meta_array(meta: dict[str, Any], path: Path, name: str, shape: tuple[int | None, ...]) -> np.ndarray:
    """A numeric entry of a file's metadata (an SE3 pose, a polyline) as float64 of ``shape`` (None: any length),
    finite: a wrong-typed entry is a :class:`Py123dFormatError`, not a numpy error some lines later."""
    try:
        value = np.asarray(meta[name], np.float64)
    except (KeyError, TypeError, ValueError):
        value = np.full(1, np.nan)  # refused below
    shaped = value.ndim == len(shape) and all(n in (None, m) for n, m in zip(shape, value.shape, strict=False))
    if not shaped or not np.isfinite(value).all():
        size = "x".join("N" if n is None else str(n) for n in shape)
        raise Py123dFormatError(path, f"expected {size} finite numbers", f"metadata.{name}")
    return value


def meta_pose(meta: dict[str, Any], path: Path, name: str) -> np.ndarray:
    """An SE3 pose of a file's metadata (x, y, z, qw, qx, qy, qz): :func:`meta_array` with a non-zero quaternion."""
    pose = meta_array(meta, path, name, (7,))
    if not pose[3:].any():
        raise Py123dFormatError(path, "the rotation is a zero quaternion", f"metadata.{name}")
    if (np.abs(pose[:3]) >= MAX_COORDINATE).any():
        raise Py123dFormatError(path, f"the position is {MAX_COORDINATE:g} m or more away", f"metadata.{name}")
    return pose


def read_table(path: Path) -> pa.Table:
    """One Arrow IPC file, whole; a missing, truncated, foreign or damaged file is a :class:`Py123dFormatError`.
    pyarrow's IPC reader checks the file's framing but not the offsets and UTF-8 inside its buffers: a damaged list
    offset crashes the process later, when a value is read (Arrow's C++ aborts or segfaults); full validation checks
    every offset first, in about a millisecond for a log's file. A damaged schema raises any of pyarrow's errors (an
    invalid type is ``ArrowNotImplementedError``)."""
    try:
        with pa.memory_map(str(path), "r") as source:
            table = pa.ipc.open_file(source).read_all()
        table.validate(full=True)
    except FileNotFoundError:
        raise Py123dFormatError(path, "missing; copy or convert this log again") from None
    except (pa.ArrowException, OSError, UnicodeDecodeError) as err:
        raise Py123dFormatError(
            path, f"not a readable Arrow IPC file ({err}); copy or convert this log again"
        ) from None
    return table


def table_metadata(table: pa.Table, path: Path) -> dict[str, Any]:
    """The msgpack metadata of a file's schema ({} where the writer stored none)."""
    raw = (table.schema.metadata or {}).get(METADATA_KEY)
    return {} if raw is None else unpack(raw, path, "metadata")


def column(table: pa.Table, path: Path, name: str) -> pa.ChunkedArray:
    if name not in table.column_names:
        raise Py123dFormatError(path, f"column missing (has {', '.join(table.column_names)})", name)
    return table[name]


def _numbers(kind: pa.DataType) -> bool:
    return pa.types.is_integer(kind) or pa.types.is_floating(kind)


def _lists_of(item: Callable[[pa.DataType], bool]) -> Callable[[pa.DataType], bool]:
    def check(kind: pa.DataType) -> bool:
        lists = pa.types.is_list(kind) or pa.types.is_large_list(kind) or pa.types.is_fixed_size_list(kind)
        return lists and item(kind.value_type)

    return check


def _bytes_or_path(kind: pa.DataType) -> bool:
    return pa.types.is_binary(kind) or pa.types.is_large_binary(kind) or pa.types.is_string(kind)


#: The columns we read (by the name after the modality key) and the Arrow types they may have; checked when a file
#: is read, so that a value of another writer's type is an error naming the column, not a numpy error in a sample.
COLUMN_TYPES: dict[str, tuple[str, Callable[[pa.DataType], bool]]] = {
    "imu_se3": ("a list of numbers", _lists_of(_numbers)),
    "dynamic_state_se3": ("a list of numbers", _lists_of(_numbers)),
    "bounding_box_se3": ("lists of number lists", _lists_of(_lists_of(_numbers))),
    "velocity_3d": ("lists of number lists", _lists_of(_lists_of(_numbers))),
    "track_token": ("a list of strings", _lists_of(pa.types.is_string)),
    "label": ("a list of integers", _lists_of(pa.types.is_integer)),
    "lane_id": ("a list of integers", _lists_of(pa.types.is_integer)),
    "status": ("a list of integers", _lists_of(pa.types.is_integer)),
    "data": ("bytes or a path", _bytes_or_path),
}


def check_columns(table: pa.Table, path: Path, key: str) -> None:
    """Every column of :data:`COLUMN_TYPES` that the file of modality ``key`` has is of its type."""
    for name, kind in zip(table.column_names, table.schema.types, strict=True):
        expected = COLUMN_TYPES.get(name.removeprefix(f"{key}."))
        if expected is not None and not expected[1](kind):
            raise Py123dFormatError(path, f"expected {expected[0]} per row, got {kind}", name)


def fixed_rows(table: pa.Table, path: Path, name: str, width: int) -> np.ndarray:
    """A column of fixed-size float lists (poses, dynamic states) as (N, width) float64; NaN rows where null."""
    values = column(table, path, name).combine_chunks()
    out = np.full((len(values), width), np.nan)
    valid = ~np.asarray(values.is_null().to_numpy(zero_copy_only=False), bool)
    if valid.any():
        flat = values.filter(pa.array(valid)).flatten().to_numpy(zero_copy_only=False)
        if flat.size != valid.sum() * width:
            raise Py123dFormatError(path, f"expected {width} numbers per row", name)
        out[valid] = flat.reshape(-1, width)
    return out


@dataclass
class LogFiles:
    """The Arrow files of one 123D log, opened lazily; ``sync`` maps iterations to each modality's rows."""

    folder: Path
    log: dict[str, Any]
    timestamps_us: np.ndarray
    sync: dict[str, np.ndarray]  # modality key -> (iterations,) int64 row index, -1 where absent
    _tables: dict[str, tuple[pa.Table, dict[str, Any]]] = field(default_factory=dict)

    @classmethod
    def open(cls, folder: Path) -> "LogFiles":
        path = folder / SYNC_FILE
        table = read_table(path)
        log = table_metadata(table, path)
        for name in ("dataset", "split", "log_name", "location"):  # the log's identity, copied into every sample
            if name not in log and name != "location":
                raise Py123dFormatError(path, "log metadata lacks this entry", f"metadata.{name}")
            if not isinstance(log.get(name), str | None if name == "location" else str):
                raise Py123dFormatError(path, f"expected a string, got {log[name]!r:.60}", f"metadata.{name}")
        stamps = _timestamps(column(table, path, "sync.timestamp_us").combine_chunks(), path)
        sync = {}
        for name in table.column_names:
            if not name.startswith("sync."):
                sync[name] = _row_indices(table[name].combine_chunks(), path, name)
                if not (folder / f"{name}.arrow").is_file():  # py123d writes a sync column per file it writes
                    raise Py123dFormatError(folder / f"{name}.arrow", "missing (sync.arrow lists it)")
        return cls(folder, log, stamps, sync)

    def has(self, key: str) -> bool:
        return key in self.sync

    def keys(self, prefix: str) -> list[str]:
        """Modality keys of one type (``camera.``, ``lidar.``) present in the sync table, sorted."""
        return sorted(key for key in self.sync if key.startswith(prefix) and self.has(key))

    def table(self, key: str) -> tuple[pa.Table, dict[str, Any]]:
        """A modality's table and its metadata, read once."""
        if key not in self._tables:
            path = self.path(key)
            table = read_table(path)
            last = int(self.sync[key].max(initial=-1))
            if last >= table.num_rows:
                problem = f"row index {last} past the {table.num_rows} rows of {path.name}"
                raise Py123dFormatError(self.folder / SYNC_FILE, problem, key)
            check_columns(table, path, key)
            self._tables[key] = table, table_metadata(table, path)
        return self._tables[key]

    def path(self, key: str) -> Path:
        return self.folder / f"{key}.arrow"

    def value(self, key: str, name: str, row: int) -> Any:
        """One cell of a modality's file as a Python value."""
        table, _ = self.table(key)
        return column(table, self.path(key), f"{key}.{name}")[row].as_py()


def _timestamps(values: pa.Array, path: Path) -> np.ndarray:
    """The iterations' int64 microseconds, which must increase (every trajectory's times come from them)."""
    if not pa.types.is_integer(values.type) or values.null_count:
        raise Py123dFormatError(path, f"expected one integer per iteration, got {values.type}", "sync.timestamp_us")
    stamps = np.asarray(values.to_numpy(zero_copy_only=False), np.int64)
    if (np.diff(stamps) <= 0).any():
        at = int(np.argmax(np.diff(stamps) <= 0)) + 1
        raise Py123dFormatError(path, f"timestamps do not increase at iteration {at}", "sync.timestamp_us")
    return stamps


def _row_indices(values: pa.Array, path: Path, name: str) -> np.ndarray:
    """A sync column as one row index per iteration (-1 where absent: null). py123d 0.7 writes one int64 per
    iteration; earlier versions wrote a list of the rows within the iteration, of which we take the first."""
    lists = pa.types.is_list(values.type) or pa.types.is_large_list(values.type)
    if lists and pa.types.is_integer(values.type.value_type):
        values = pa.array([rows[0] if rows else None for rows in values.to_pylist()], pa.int64())  # a few thousand
    if not pa.types.is_integer(values.type):
        raise Py123dFormatError(path, f"expected integer row indices, got {values.type}", name)
    rows = np.asarray(values.fill_null(-1).to_numpy(zero_copy_only=False)).astype(np.int64)
    negative = np.asarray(values.is_valid()) & (rows < 0)  # a uint64 past int64 wraps round to negative too
    if negative.any():
        raise Py123dFormatError(path, f"negative row index {rows[negative][0]}", name)
    return rows


def decode_points(blob: bytes, path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A LiDAR payload -> (N, 3) float64 xyz and per-point features, for py123d's three binary codecs."""
    if blob[:4] == b"\xff\xff\xff\xff":  # Arrow IPC stream (codecs ipc, ipc_zstd, ipc_lz4)
        columns = _ipc_columns(blob, path)
    elif blob[:4] == b"LASF":
        columns = _laz_columns(blob, path)
    else:
        raise Py123dFormatError(
            path, "LiDAR payload is neither Arrow IPC nor LAZ (Draco and file paths are not read)", "data"
        )
    try:
        xyz = np.column_stack([columns.pop(axis) for axis in "xyz"]).astype(np.float64)
    except KeyError:
        raise Py123dFormatError(path, "LiDAR payload lacks x, y or z", "data") from None
    return xyz, columns


def _ipc_columns(blob: bytes, path: Path) -> dict[str, np.ndarray]:
    """An Arrow IPC stream payload's columns, each of numbers; validated in full as :func:`read_table` does."""
    try:
        batch = pa.ipc.open_stream(pa.BufferReader(blob)).read_next_batch()  # StopIteration: a stream of no batch
        batch.validate(full=True)
        names = batch.schema.names
    except (pa.ArrowException, OSError, UnicodeDecodeError, StopIteration) as err:
        raise Py123dFormatError(path, f"LiDAR payload is not an Arrow stream ({err!r})", "data") from None
    for name, kind in zip(names, batch.schema.types, strict=True):
        if not _numbers(kind):
            raise Py123dFormatError(path, f"LiDAR payload column {name!r} is {kind}, not numbers", "data")
    return {name: batch.column(i).to_numpy(zero_copy_only=False) for i, name in enumerate(names)}


def _laz_columns(blob: bytes, path: Path) -> dict[str, np.ndarray]:
    """A LAZ payload's columns, decoded in the LAZ helper process: a damaged chunk table aborts lazrs' process
    (:mod:`lead_s2r_adapters.laz_decoder`), so the payload goes to the helper as a temporary file."""
    if importlib.util.find_spec("laspy") is None or importlib.util.find_spec("lazrs") is None:
        raise UserError(f"{path}: LAZ-coded LiDAR needs laspy[lazrs]: {INSTALL}")
    with tempfile.NamedTemporaryFile(suffix=".laz") as file:
        file.write(blob)
        file.flush()
        try:
            columns = decode_every(Path(file.name))
        except LazDecodeError as err:
            raise Py123dFormatError(path, f"LiDAR payload is not valid LAZ ({err})", "data") from None
    # py123d's features, ``extra_`` where a LAS name clashed
    return {name if name in ("x", "y", "z") else name.removeprefix("extra_"): v for name, v in columns.items()}
