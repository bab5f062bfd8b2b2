"""Webdataset shards of schema v1 samples: encode, write with roll-back, read, and the manifest.

Tar members are ``<key>.<field>.<ext>`` (``meta.json``, ``future.npy``, ``cam_front.jpg``...). Arrays are stored
with ``np.save(allow_pickle=False)``, JPEG bytes untouched, nothing is pickled. Shards are written by our own
small tar writer (deterministic headers, and :meth:`ShardFile.rollback` to drop a half-written log) and read
with webdataset, which is imported where it reads: it brings torch (4 s of start-up), and conversion workers, which
only write, are spawned processes that must not pay it.
"""

import io
import json
import os
import tarfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from lead_s2r.schema import field_spec

MANIFEST = "manifest.parquet"
INFO = "info.json"
ERRORS = "errors.jsonl"
SHARD_DIR = "shards"
_BLOCK = 512


def encode_field(name: str, value: Any) -> bytes:
    """Bytes of one field as stored in the tar member ``<key>.<name>.<ext>``."""
    ext = field_spec(name).ext
    if ext == "jpg":
        return bytes(value)
    if ext == "json":
        return json.dumps(value, allow_nan=False, separators=(",", ":")).encode()
    buffer = io.BytesIO()
    if ext == "npy":
        np.save(buffer, value, allow_pickle=False)
    elif ext == "npz":
        np.savez_compressed(buffer, **value)
    elif ext == "png":
        ok, png = cv2.imencode(".png", value)
        if not ok:
            raise ValueError(f"field {name!r}: cannot encode PNG from array of shape {value.shape}")
        return png.tobytes()
    return buffer.getvalue()


def decode_field(name: str, data: bytes) -> Any:
    """Inverse of :func:`encode_field`; JPEG stays bytes (decode it where the pixels are needed)."""
    ext = field_spec(name).ext
    if ext == "jpg":
        return data
    if ext == "json":
        return json.loads(data)
    if ext == "png":
        return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    loaded = np.load(io.BytesIO(data), allow_pickle=False)
    if ext == "npz":
        with loaded:
            return {k: loaded[k] for k in loaded.files}
    return loaded


def encode_sample(sample: dict[str, Any]) -> list[tuple[str, bytes]]:
    """Tar members of one sample, ``meta`` first."""
    key = sample["__key__"]
    names = ["meta", *sorted(n for n in sample if n not in ("__key__", "meta"))]
    return [(f"{key}.{name}.{field_spec(name).ext}", encode_field(name, sample[name])) for name in names]


class ShardFile:
    """One tar being written to ``<path>.partial``; renamed to ``<path>`` on :meth:`close`.

    Headers carry mtime 0 and no owner, so the same samples give the same bytes.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.partial = self.path.with_name(self.path.name + ".partial")
        self._file = open(self.partial, "wb")  # noqa: SIM115 - closed in close()/abort()
        self.count = 0

    def write(self, sample: dict[str, Any]) -> None:
        for name, data in encode_sample(sample):
            info = tarfile.TarInfo(name)
            info.size = len(data)
            info.mode = 0o444
            self._file.write(info.tobuf(format=tarfile.PAX_FORMAT))
            self._file.write(data)
            self._file.write(b"\0" * (-len(data) % _BLOCK))
        self.count += 1

    def mark(self) -> tuple[int, int]:
        """A position to :meth:`rollback` to."""
        return self._file.tell(), self.count

    def rollback(self, mark: tuple[int, int]) -> None:
        """Drop everything written since ``mark`` (a log that failed half-way)."""
        offset, self.count = mark
        self._file.seek(offset)
        self._file.truncate()

    def close(self) -> Path:
        """Finish the tar, make it durable, and give it its final name."""
        self._file.write(b"\0" * (2 * _BLOCK))
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self.partial, self.path)
        return self.path

    def abort(self) -> None:
        self._file.close()
        self.partial.unlink(missing_ok=True)


def shard_paths(path: str | Path) -> list[str]:
    """Shard files of a converted folder (or a single shard, or a folder of shards), sorted."""
    path = Path(path)
    if path.is_file():
        return [str(path)]
    folder = path / SHARD_DIR if (path / SHARD_DIR).is_dir() else path
    shards = sorted(str(p) for p in folder.glob("*.tar"))
    if not shards:
        raise FileNotFoundError(f"no shards (*.tar) under {folder}")
    return shards


def decode_sample(raw: dict[str, Any], fields: Iterable[str] | None = None) -> dict[str, Any]:
    """Decode a webdataset raw sample (``{'meta.json': bytes, ...}``), only the requested fields."""
    wanted = None if fields is None else set(fields) | {"meta"}
    sample: dict[str, Any] = {"__key__": raw["__key__"]}
    for member, data in raw.items():
        if member.startswith("__"):
            continue
        name = member.rsplit(".", 1)[0]
        if wanted is None or name in wanted:
            sample[name] = decode_field(name, data)
    return sample


def read_samples(path: str | Path, fields: Iterable[str] | None = None) -> Iterator[dict[str, Any]]:
    """Yield decoded samples from a converted folder or shard(s), in shard order.

    ``fields`` limits decoding to those fields (``meta`` is always decoded).
    """
    import webdataset as wds  # here, not at the top: see the module docstring

    fields = None if fields is None else tuple(fields)
    dataset = wds.WebDataset(shard_paths(path), shardshuffle=False, empty_check=False)
    for raw in dataset:
        yield decode_sample(raw, fields)


def load_manifest(path: str | Path) -> pa.Table:
    """The manifest table of a converted folder: one row per sample, no blobs."""
    path = Path(path)
    return pq.read_table(path / MANIFEST if path.is_dir() else path)


def load_info(path: str | Path) -> dict[str, Any]:
    """``info.json`` of a converted folder."""
    return json.loads((Path(path) / INFO).read_text())
