"""Random corruptions of one file of a raw or converted data folder, for the fuzz test (tests/test_fuzz.py).

A trial copies a pristine folder as hard links (cheap) and replaces one file by a corrupted copy, so the pristine
folder is never written. The corruptions are the ones disks, copies and people cause: flipped bytes, a truncated
file, a zeroed or random span, a deleted file, garbage appended, and a structured file (JSON, YAML, LEAD's LZMA
pickles, 123D's Arrow IPC files) re-written with one value of the wrong type; and damages that regression tests
share (:func:`aborting_laz`, :func:`flip_in_value`, :func:`flip_footer_byte`).
"""

import json
import lzma
import os
import pickle
import shutil
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import yaml

KINDS = ("flip", "truncate", "zero_span", "random_span", "delete", "append", "wrong_type")
#: Values that replace one of a structured file's values; each is a type the reader does not expect there.
WRONG_VALUES: tuple[Any, ...] = (None, 7, -1.5, "x", [], {}, [1, "a"], {"k": None}, True)


def hardlink_copy(src: Path, dst: Path) -> None:
    """A copy of the folder ``src`` whose files are hard links: a trial replaces a file instead of writing it."""
    shutil.copytree(src, dst, copy_function=os.link)


def _replace(path: Path, data: bytes) -> None:
    """Write ``data`` as a new file at ``path``, leaving the hard-linked original untouched."""
    path.unlink()
    path.write_bytes(data)


def _wrong_typed(value: Any, rng: np.random.Generator) -> Any:
    """``value`` with one nested value (a dict entry or list item, at any depth) of a wrong type."""
    containers = []

    def walk(node: Any) -> None:
        if isinstance(node, dict) and node:
            containers.append(node)
            for child in node.values():
                walk(child)
        elif isinstance(node, list) and node:
            containers.append(node)
            for child in node[:8]:
                walk(child)

    walk(value)
    wrong = WRONG_VALUES[int(rng.integers(len(WRONG_VALUES)))]
    if not containers:
        return wrong
    node = containers[int(rng.integers(len(containers)))]
    if isinstance(node, dict):
        node[list(node)[int(rng.integers(len(node)))]] = wrong
    else:
        node[int(rng.integers(len(node)))] = wrong
    return value


def _retype(path: Path, data: bytes, rng: np.random.Generator) -> bytes | None:
    """The file's content with one value of the wrong type, or None when it is not a structured file."""
    suffix = path.suffix
    try:
        if suffix == ".json":
            return json.dumps(_wrong_typed(json.loads(data), rng)).encode()
        if suffix == ".yaml":
            return yaml.safe_dump(_wrong_typed(yaml.safe_load(data), rng)).encode()
        if suffix == ".pkl" and data[:1] == b"\xfd":  # LEAD: an LZMA (xz) stream holding a pickle
            return lzma.compress(pickle.dumps(_wrong_typed(pickle.loads(lzma.decompress(data)), rng)))
        if suffix == ".pkl":  # OpenScene logs: a plain pickle of a list of frame dicts
            return pickle.dumps(_wrong_typed(pickle.loads(data), rng))
        if suffix == ".arrow":
            return _retyped_arrow(data, rng)
    except (ValueError, yaml.YAMLError, lzma.LZMAError, pickle.UnpicklingError):
        return None
    return None


def _retyped_arrow(data: bytes, rng: np.random.Generator) -> bytes:
    """A 123D Arrow IPC file re-written with one wrong-typed value: in the msgpack metadata of its schema, in the
    msgpack fields of one map object, or a whole column replaced by one of another type (another writer's file)."""
    import msgpack
    import pyarrow as pa

    table = pa.ipc.open_file(pa.BufferReader(data)).read_all()
    metadata = dict(table.schema.metadata or {})
    places = ["column", *(["metadata"] if b"metadata" in metadata else []), *(["map"] if "features" in table else [])]
    place = places[int(rng.integers(len(places)))]
    if place == "metadata":
        meta = msgpack.unpackb(metadata[b"metadata"], raw=False, strict_map_key=False)
        metadata[b"metadata"] = msgpack.packb(_wrong_typed(meta, rng))
    elif place == "map":
        features = table["features"].to_pylist()
        at = int(rng.integers(len(features)))
        features[at] = msgpack.packb(_wrong_typed(msgpack.unpackb(features[at], strict_map_key=False), rng))
        table = table.set_column(table.column_names.index("features"), "features", pa.array(features, pa.binary()))
    else:
        at = int(rng.integers(table.num_columns))
        wrong = WRONG_VALUES[int(rng.integers(len(WRONG_VALUES)))]
        try:
            values = pa.array([wrong] * table.num_rows)
        except pa.ArrowInvalid:  # [1, "a"]: no Arrow type holds it
            values = pa.array(["x"] * table.num_rows)
        table = table.set_column(at, table.column_names[at], values)
    sink = pa.BufferOutputStream()
    with pa.ipc.new_file(sink, table.schema.with_metadata(metadata)) as writer:
        writer.write_table(table)
    return sink.getvalue().to_pybytes()


def corrupt(path: Path, kind: str, rng: np.random.Generator) -> str:
    """Corrupt the file ``path`` in the way ``kind`` names; returns what was done, for the failure message."""
    if kind == "delete":
        path.unlink()
        return f"deleted {path}"
    data = bytearray(path.read_bytes())
    size = len(data)
    if kind == "wrong_type":
        retyped = _retype(path, bytes(data), rng)
        if retyped is not None:
            _replace(path, retyped)
            return f"one value of {path} of a wrong type"
        kind = "flip"
    if size == 0 or kind == "append":
        _replace(path, bytes(data) + rng.bytes(int(rng.integers(1, 600))))
        return f"garbage appended to {path}"
    start = int(rng.integers(size))
    span = int(rng.integers(1, min(size - start, 512) + 1))
    if kind == "flip":
        for at in rng.integers(size, size=int(rng.integers(1, 9))):
            data[at] ^= 1 << int(rng.integers(8))
    elif kind == "truncate":
        data = data[:start]
    elif kind == "zero_span":
        data[start : start + span] = bytes(span)
    elif kind == "random_span":
        data[start : start + span] = rng.bytes(span)
    _replace(path, bytes(data))
    return f"{kind} of {path} at byte {start}"


def flip_in_value(path: Path, value: bytes) -> None:
    """Flip the lowest bit of the first place ``path`` stores ``value`` (a number's bytes): a damaged digit that
    leaves the file's structure whole, so only a checksum can tell."""
    data = bytearray(path.read_bytes())
    data[data.index(value)] ^= 1
    _replace(path, bytes(data))


def parquet_footer(data: bytes) -> int:
    """Where a parquet file's footer (its thrift FileMetaData) starts: its length sits before the closing magic."""
    return len(data) - 8 - int.from_bytes(data[-8:-4], "little")


def flip_footer_byte(path: Path, wanted: Callable[[Path], bool]) -> None:
    """Flip bit 1 of the first footer byte for which ``wanted(path)`` holds (thrift keeps no offsets to look up)."""
    data = path.read_bytes()
    for at in range(parquet_footer(data), len(data) - 8):
        _replace(path, data[:at] + bytes([data[at] ^ 2]) + data[at + 1 :])
        try:
            if wanted(path):
                return
        except (OSError, pa.ArrowException):
            pass
    raise AssertionError("no such footer byte")


def aborting_laz(data: bytes) -> bytes:
    """A LAZ file whose chunk table claims 2**31 - 1 chunks: lazrs asks for 34 GB and aborts its process."""
    out = bytearray(data)
    points_at = struct.unpack_from("<I", out, 96)[0]  # LAS header: offset to point data
    table_at = struct.unpack_from("<q", out, points_at)[0]  # LAZ: the chunk table's offset comes first
    struct.pack_into("<I", out, table_at + 4, 0x7FFFFFFF)  # chunk table: version, number of chunks
    return bytes(out)


def pick_file(root: Path, rng: np.random.Generator, weight: Callable[[Path], float] = lambda p: 1.0) -> Path:
    """One file under ``root``, drawn with probability proportional to ``weight`` (e.g. rare kinds up-weighted)."""
    files = sorted(p for p in root.rglob("*") if p.is_file())
    weights = np.array([weight(p) for p in files], dtype=np.float64)
    return files[int(rng.choice(len(files), p=weights / weights.sum()))]
