"""TFRecord framing without TensorFlow: sequential scan, random access, and a one-pass record index.

A record is ``uint64 length | uint32 masked_crc(length) | payload | uint32 masked_crc(payload)``, all
little-endian; CRCs are CRC-32C (Castagnoli), masked as TensorFlow does. Both CRCs are verified on every read,
because a corrupt record that still parses as a protobuf would silently become a wrong training sample.
Offsets always point at the start of a record (its length field), lengths are payload lengths.
"""

import json
import multiprocessing
import os
import struct
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import crc32c
import pyarrow as pa

from lead_s2r.errors import UserError
from lead_s2r.files import read_parquet, write_parquet
from lead_s2r.processes import exit_with_parent

HEADER = 12  # uint64 length + uint32 crc of the length
FOOTER = 4  # uint32 crc of the payload
_MASK_DELTA = 0xA282EAD8
_INDEX_COLUMNS = {"shard": pa.string(), "offset": pa.int64(), "length": pa.int64()}
_STAMP_KEY = b"lead_s2r.shards"
_SKIPPED_KEY = b"lead_s2r.skipped"


class TFRecordError(UserError, ValueError):
    """A record that cannot be trusted; names the shard and the byte offset of the record."""

    def __init__(self, path: str | Path, offset: int, problem: str, framing_intact: bool = False) -> None:
        super().__init__(f"{path}: record at offset {offset}: {problem}")
        self.path = str(path)
        self.offset = offset
        #: True when the next record can still be found (only the payload is bad).
        self.framing_intact = framing_intact


def masked_crc32c(data: bytes | memoryview) -> int:
    """TensorFlow's masked CRC-32C: rotate right by 15 bits, then add a constant (mod 2^32)."""
    crc = crc32c.crc32c(data)
    return (((crc >> 15) | (crc << 17)) + _MASK_DELTA) & 0xFFFFFFFF


def _parse_header(path: str | Path, offset: int, header: bytes) -> int:
    if len(header) < HEADER:
        raise TFRecordError(path, offset, f"truncated header ({len(header)} of {HEADER} bytes)")
    length, length_crc = struct.unpack("<QI", header[:HEADER])
    if masked_crc32c(header[:8]) != length_crc:
        raise TFRecordError(path, offset, "length CRC mismatch (corrupt header)")
    return length


def _check_payload(path: str | Path, offset: int, length: int, body: bytes) -> bytes:
    if len(body) < length + FOOTER:
        raise TFRecordError(path, offset, f"truncated record ({len(body)} of {length + FOOTER} payload+CRC bytes)")
    payload = body[:length]
    (payload_crc,) = struct.unpack("<I", body[length : length + FOOTER])
    if masked_crc32c(payload) != payload_crc:
        raise TFRecordError(path, offset, "payload CRC mismatch", framing_intact=True)
    return payload


class Record(NamedTuple):
    """One verified record of a shard."""

    offset: int
    payload: bytes


def iter_records(path: str | Path) -> Iterator[Record | TFRecordError]:
    """Every record of a shard in file order; a bad record is yielded as its :class:`TFRecordError`. A payload with a
    bad CRC is skipped and the scan goes on (its framing is intact); a bad length CRC or a truncated record ends the
    scan, since nothing after it can be located reliably."""
    with open(path, "rb") as file:
        offset = 0
        while header := file.read(HEADER):
            try:
                length = _parse_header(path, offset, header)
                body = file.read(length + FOOTER)
                yield Record(offset, _check_payload(path, offset, length, body))
            except TFRecordError as err:
                yield err
                if not err.framing_intact:
                    return
            offset += HEADER + length + FOOTER


class RecordReader:
    """Random access to records by (shard, offset, length); keeps shards open until :meth:`close`."""

    def __init__(self) -> None:
        self._fds: dict[str, int] = {}

    def read(self, path: str | Path, offset: int, length: int) -> bytes:
        """The verified payload of the record at ``offset``; its length must equal ``length`` (from the index)."""
        path = str(path)
        fd = self._fds.get(path)
        if fd is None:
            fd = self._fds[path] = os.open(path, os.O_RDONLY)
        data = os.pread(fd, HEADER + length + FOOTER, offset)
        stored = _parse_header(path, offset, data[:HEADER])
        if stored != length:
            raise TFRecordError(path, offset, f"length {stored} differs from the index ({length}); re-index")
        return _check_payload(path, offset, length, data[HEADER:])

    def close(self) -> None:
        for fd in self._fds.values():
            os.close(fd)
        self._fds.clear()

    def __enter__(self) -> "RecordReader":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: Extracts index columns from one payload; raises ValueError for a payload of the wrong kind.
Describe = Callable[[bytes], dict[str, Any]]


@dataclass
class RecordIndex:
    """Where every good record lives (``table``: shard, offset, length + described columns) and what was skipped."""

    table: pa.Table
    skipped: list[dict[str, Any]]


def _stamp(shards: Iterable[Path]) -> str:
    """Identity of a shard set (names, sizes, mtimes): a cached index is reused only while it matches."""
    return json.dumps({str(p): [p.stat().st_size, p.stat().st_mtime_ns] for p in sorted(shards)}, sort_keys=True)


def _index_shard(shard: Path, describe: Describe) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    rows: list[dict[str, Any]] = []
    skipped: list[dict[str, Any]] = []
    for item in iter_records(shard):
        if isinstance(item, TFRecordError):
            skipped.append({"shard": item.path, "offset": item.offset, "error": str(item)})
            continue
        try:
            columns = describe(item.payload)
        except ValueError as err:
            error = f"{shard}: record at offset {item.offset}: {err}"
            skipped.append({"shard": str(shard), "offset": item.offset, "error": error})
            continue
        rows.append({"shard": str(shard), "offset": item.offset, "length": len(item.payload), **columns})
    return rows, skipped


def build_index(
    shards: list[Path], describe: Describe, schema: dict[str, pa.DataType], workers: int = 1
) -> RecordIndex:
    """One pass over ``shards`` (``workers`` processes): a row per good record, a ``skipped`` entry per bad one.
    ``describe`` (picklable when ``workers > 1``) adds the columns of ``schema``; a ValueError from it skips the record.
    """
    if workers > 1:
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(workers, context, initializer=exit_with_parent) as pool:
            parts = list(pool.map(_index_shard, shards, [describe] * len(shards)))
    else:
        parts = [_index_shard(shard, describe) for shard in shards]
    types = {**_INDEX_COLUMNS, **schema}
    rows = [row for part_rows, _ in parts for row in part_rows]
    table = pa.table({name: pa.array([row[name] for row in rows], kind) for name, kind in types.items()})
    return RecordIndex(table, [entry for _, part_skipped in parts for entry in part_skipped])


def cached_index(
    shards: list[Path], describe: Describe, schema: dict[str, pa.DataType], cache: Path | None, workers: int = 1
) -> RecordIndex:
    """:func:`build_index`, stored at ``cache`` (parquet, skipped records in its metadata) and reused while valid.

    A stale or damaged cache is rebuilt: its pages carry CRCs, the stamp covers the shards and the skipped records'
    JSON, and the columns must be the index's (no page CRC protects the footer, where one flipped bit turns the
    offsets' int64 into Arrow's duration), so a flipped bit never passes for another index."""
    stamp = _stamp(shards)
    if cache is not None and cache.exists():
        try:
            table = read_parquet(cache)
            metadata = table.schema.metadata or {}
            skipped = metadata[_SKIPPED_KEY]
            table = table.replace_schema_metadata(None)
            same_columns = table.schema == pa.schema({**_INDEX_COLUMNS, **schema})
            if same_columns and metadata[_STAMP_KEY].decode() == _cache_stamp(stamp, skipped):
                return RecordIndex(table, json.loads(skipped))
        except (OSError, KeyError, ValueError, pa.ArrowException):
            pass  # damaged: rebuilt below, as a stale one is
    index = build_index(shards, describe, schema, workers)
    if cache is not None:
        skipped = json.dumps(index.skipped).encode()
        metadata = {_STAMP_KEY: _cache_stamp(stamp, skipped).encode(), _SKIPPED_KEY: skipped}
        write_parquet(cache, index.table.replace_schema_metadata(metadata))
    return index


def _cache_stamp(shards_stamp: str, skipped: bytes) -> str:
    return f"{shards_stamp} skipped:{crc32c.crc32c(skipped)}"
