"""Webdataset shards of schema v1 samples: encode, write with roll-back, read, and the manifest.

Tar members are ``<key>.<field>.<ext>`` (``meta.json``, ``future.npy``, ``cam_front.jpg``...). Arrays are stored
with ``np.save(allow_pickle=False)``, JPEG bytes untouched, nothing is pickled. Shards are written by our own
small tar writer (deterministic headers: the same samples give the same bytes) and read by our own reader
(:class:`TarSamples`), which webdataset's pipelines in ``data/`` use as a stage; this module does not import
webdataset, which brings torch (4 s of start-up) into every process that reads or writes a shard. A tar is a
sequence of members closed by two zero blocks, so the members of one log written to a file of their own
(:func:`write_sample`) and appended to a shard (:meth:`ShardFile.append`) give the bytes :meth:`ShardFile.write`
gives: conversion workers write logs apart and the driver puts them in order.

Reading trusts nothing: a tar cut at a member boundary reads as a shorter, valid stream (tarfile raises nothing),
so :func:`shard_paths` checks that every shard ends with the two zero blocks :meth:`ShardFile.close` writes; a tar
cut inside a member, an undecodable member or an array of another dtype than the schema's is a
:class:`ShardError` naming the tar, the sample key and the field. A corrupt header in the middle of a tar ends
tarfile's stream there, silently too (it raises only at offset 0), so the reader of a converted folder holds every
tar against the keys the manifest lists for it (:class:`ManifestCheck`): one parquet column, read once.
"""

import errno
import io
import json
import os
import re
import shutil
import tarfile
import zipfile
import zlib
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from tokenize import TokenError
from typing import Any, BinaryIO

import cv2
import numpy as np
import pyarrow as pa

from lead_s2r.errors import UserError
from lead_s2r.files import move_into_place, read_parquet, write_parquet
from lead_s2r.schema import REQUIRED_FIELDS, field_spec

MANIFEST = "manifest.parquet"
INFO = "info.json"
ERRORS = "errors.jsonl"
#: Written by ``convert`` before its first shard: the folder is a conversion, whose readers need its manifest.
IDENTITY = "convert.json"
SHARD_DIR = "shards"
_BLOCK = 512
_END_OF_ARCHIVE = 2 * _BLOCK
_REDO = "re-run lead-s2r convert (with --force) to rewrite it"


class ShardError(UserError):
    """A converted folder or shard that cannot be read as written; names the folder or tar, key and field."""


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


def write_sample(file: BinaryIO, sample: dict[str, Any]) -> None:
    """Write the tar members of one sample to ``file``; headers carry mtime 0 and no owner, so the same samples give
    the same bytes."""
    for name, data in encode_sample(sample):
        info = tarfile.TarInfo(name)
        info.size = len(data)
        info.mode = 0o444
        file.write(info.tobuf(format=tarfile.PAX_FORMAT))
        file.write(data)
        file.write(b"\0" * (-len(data) % _BLOCK))


def _copy_in_kernel(source: int, target: int, size: int) -> bool:
    """``copy_file_range`` of ``size`` bytes at both files' positions; False, having copied nothing, where the
    platform (not Linux) or the file system refuses it."""
    if not hasattr(os, "copy_file_range"):
        return False
    done = 0
    while done < size:
        try:
            copied = os.copy_file_range(source, target, size - done)
        except OSError as err:
            if done or err.errno not in (errno.ENOSYS, errno.EXDEV, errno.EOPNOTSUPP, errno.EINVAL):
                raise
            return False
        if copied == 0:
            raise OSError(f"file descriptor {source} ended {size - done} bytes early while copying it")
        done += copied
    return True


class ShardFile:
    """One tar being written to ``<path>.partial``; renamed to ``<path>`` on :meth:`close`."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.partial = self.path.with_name(self.path.name + ".partial")
        self._file = open(self.partial, "wb")  # noqa: SIM115 - closed in close()/abort()
        self.count = 0

    def write(self, sample: dict[str, Any]) -> None:
        write_sample(self._file, sample)
        self.count += 1

    def append(self, fragment: Path, count: int) -> None:
        """Append the ``count`` samples :func:`write_sample` wrote to the file ``fragment``, byte for byte: in the
        kernel where it can, with no trip through Python."""
        self._file.flush()
        with open(fragment, "rb") as source:
            if not _copy_in_kernel(source.fileno(), self._file.fileno(), os.fstat(source.fileno()).st_size):
                shutil.copyfileobj(source, self._file)
        self._file.seek(0, os.SEEK_END)  # the buffered file object learns where the kernel left the end
        self.count += count

    def close(self) -> Path:
        """Finish the tar, make it durable, and give it its final name."""
        self._file.write(b"\0" * _END_OF_ARCHIVE)
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        move_into_place(self.partial, self.path)
        return self.path

    def abort(self) -> None:
        self._file.close()
        self.partial.unlink(missing_ok=True)


def shard_paths(path: str | Path) -> list[str]:
    """Shard files of a converted folder (or a single shard, or a folder of shards), sorted, each checked whole."""
    path = Path(path)
    if not path.exists():
        raise ShardError(f"{path} does not exist; give a folder written by lead-s2r convert")
    if path.is_file():
        shards = [str(path)]
    else:
        folder = path / SHARD_DIR if (path / SHARD_DIR).is_dir() else path
        shards = sorted(str(p) for p in folder.glob("*.tar"))
        if not shards:
            raise ShardError(f"no shards (*.tar) under {folder}; give a folder written by lead-s2r convert")
    for shard in shards:  # whole: ends with the end-of-archive blocks a closed shard has
        with open(shard, "rb") as file:
            size = file.seek(0, os.SEEK_END)
            file.seek(max(size - _END_OF_ARCHIVE, 0))
            tail = file.read()
        if size % _BLOCK or size < _END_OF_ARCHIVE or tail.count(0) != len(tail):
            raise ShardError(f"{shard}: truncated tar ({size} bytes, no end-of-archive blocks); {_REDO}")
    return shards


#: webdataset's split of a member name into the sample key and the field's suffix (``tariterators.base_plus_ext``),
#: and the metadata members it skips.
_MEMBER_NAME = re.compile(r"^((?:.*/|)[^.]+)[.]([^/]*)$")
_TAR_META = re.compile(r"__[^/]*__($|/)")


class TarSamples:
    """Every reader's tar reader, and a webdataset stage (``{"url": tar}`` items in): a tar's raw samples grouped as
    webdataset's ``tarfile_to_samples`` groups them (``__key__``, ``__url__``, each member's bytes under its
    lower-cased suffix ``<field>.<ext>``), except that only the members of ``fields`` (and ``meta``) are read; the
    others are listed with no bytes (``b""``) for :func:`decode_sample`'s completeness check. ``fields`` None reads
    every member.

    Why not webdataset's own: it reads a tar as a stream (tarfile's ``r|*`` mode), so tarfile reads a member's bytes
    in 8 KB pieces and joins and slices them (a realistic CARLA frame's 1 MB LiDAR array: about 120 Python calls and
    three copies), and it reads every member, decoded or not: 0.8-1.2 ms a realistic CARLA sample, against 0.35-0.45 ms
    here, where each wanted member is one read of the opened file (docs/benchmarks.md, "Eighth round"); and it cannot
    start at a sample inside a tar, which a parallel reader's parts do (:func:`read_part`). A tar that cannot be read
    is a :class:`ShardError` naming it; a header that ends the tar early ends it quietly (tarfile's behaviour, as in
    webdataset's), which :func:`decode_sample` and :class:`ManifestCheck` catch.
    """

    def __init__(self, fields: Iterable[str] | None = None) -> None:
        self.wanted = None if fields is None else {*fields, "meta"}

    def __call__(self, sources: Iterable[Mapping[str, str]]) -> Iterator[dict[str, Any]]:
        for source in sources:
            yield from self.read(source["url"])

    def read(self, shard: str, offset: int = 0) -> Iterator[dict[str, Any]]:
        """The raw samples of the tar ``shard`` from byte ``offset`` on (a sample's first header:
        :func:`sample_offsets`), in order."""
        try:
            with open(shard, "rb") as file:
                file.seek(offset)
                yield from self._samples(shard, file)
        except (OSError, tarfile.TarError) as err:
            problem = (err.strerror if isinstance(err, OSError) else None) or str(err)
            raise ShardError(f"{shard}: cannot be read ({problem}); the tar is truncated or corrupt: {_REDO}") from err

    def _samples(self, shard: str, file: BinaryIO) -> Iterator[dict[str, Any]]:
        with tarfile.open(fileobj=file, mode="r:") as tar:  # reads from where the file stands
            raw: dict[str, Any] | None = None
            for member in tar:
                named = _MEMBER_NAME.match(member.name) if member.isreg() else None
                if named is None or _TAR_META.match(member.name):
                    continue
                key, suffix = named.group(1), named.group(2).lower()
                if raw is None or key != raw["__key__"]:
                    if raw is not None:
                        yield raw
                    raw = {"__key__": key, "__url__": shard}
                if suffix in raw:
                    raise ShardError(f"{shard}: sample {key!r} holds {suffix!r} twice; {_REDO}")
                wanted = self.wanted is None or suffix.rsplit(".", 1)[0] in self.wanted
                raw[suffix] = self._member_bytes(file, member) if wanted else b""
            if raw is not None:
                yield raw

    @staticmethod
    def _member_bytes(file: BinaryIO, member: tarfile.TarInfo) -> bytes:
        file.seek(member.offset_data)
        data = file.read(member.size)
        if len(data) != member.size:
            raise tarfile.ReadError("unexpected end of data")
        return data


def listed_keys(path: str | Path) -> dict[str, list[str]] | None:
    """Keys the manifest lists per shard (see :func:`keys_by_shard`); None without a manifest (a plain folder of tars).
    ``path`` is a converted folder, its shard folder or one of its shards."""
    path = Path(path)
    folder = path
    if path.is_file() and path.parent.name == SHARD_DIR:
        folder = path.parent.parent
    elif path.name == SHARD_DIR:
        folder = path.parent
    if not (folder / MANIFEST).is_file():
        if (folder / IDENTITY).is_file():  # convert wrote here: its manifest is lost, or it never finished
            raise ShardError(f"{folder} has no {MANIFEST}: its conversion did not finish or it was deleted; {_REDO}")
        return None
    return keys_by_shard((row["shard"], row["key"]) for row in listed_samples(folder, check=False))


def keys_by_shard(samples: Iterable[tuple[str, str]]) -> dict[str, list[str]]:
    """(shard, key) pairs -> the keys of each shard, in their order; shards in first-seen order."""
    listed: dict[str, list[str]] = {}
    for shard, key in samples:
        listed.setdefault(shard, []).append(key)
    return listed


def listed_samples(folder: Path, columns: Sequence[str] = (), check: bool = True) -> list[dict[str, Any]]:
    """Every sample the manifest of the converted ``folder`` lists, as its manifest row (``key``, ``shard`` spelt as
    :func:`shard_paths` spells it, and ``columns``), in shard order (the manifest's within a shard): the one way a
    reader chooses samples without decoding any. With ``check``, a tar the manifest lists that the folder lacks is a
    :class:`ShardError`."""
    rows = load_manifest(folder, columns=("key", "shard", *columns)).to_pylist()
    for row in rows:
        row["shard"] = str(folder / SHARD_DIR / row["shard"])
    rows.sort(key=lambda row: row["shard"])  # stable
    if check:
        check_listed_shards(keys_by_shard((row["shard"], row["key"]) for row in rows))
    return rows


def check_listed_shards(listed: Mapping[str, Sequence[str]]) -> None:
    """Raise :class:`ShardError` naming the first tar the manifest lists samples in that is not on disk: a deleted
    tar is otherwise a shorter, valid-looking folder."""
    for shard, keys in sorted(listed.items()):
        if not os.path.isfile(shard):
            raise ShardError(f"{shard}: missing, but {MANIFEST} lists {len(keys)} samples in it; {_REDO}")


class ManifestCheck:
    """A webdataset stage over raw samples: passes them on, and raises :class:`ShardError` naming the tar when a tar
    yields a key its manifest rows do not list, or fewer samples than they list. Each tar's count is checked when the
    next tar starts or the stream ends, so the stream must open every tar once (evaluation, :func:`read_samples`; not
    the resampled training stream). A tar that yields nothing cannot slip through: a bad first header is a
    ``ReadError`` that :class:`TarSamples` names."""

    def __init__(self, listed: Mapping[str, Sequence[str]]) -> None:
        self.listed = {shard: frozenset(keys) for shard, keys in listed.items()}

    def __call__(self, raws: Iterable[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        shard, count = None, 0
        for raw in raws:
            if raw["__url__"] != shard:
                self._check_count(shard, count)
                shard, count = raw["__url__"], 0
            if raw["__key__"] not in self.listed.get(shard, ()):
                raise ShardError(
                    f"{shard}: sample {raw['__key__']!r} is not in the manifest (a corrupt tar header, or a tar "
                    f"from another conversion); {_REDO}"
                )
            count += 1
            yield raw
        self._check_count(shard, count)

    def _check_count(self, shard: str | None, count: int) -> None:
        if shard is not None and count < len(self.listed[shard]):
            raise ShardError(
                f"{shard}: read {count} of the {len(self.listed[shard])} samples the manifest lists (a corrupt tar "
                f"header ends the tar there); {_REDO}"
            )


def decode_sample(raw: dict[str, Any], fields: Iterable[str] | None = None) -> dict[str, Any]:
    """Decode a webdataset raw sample (``{'meta.json': bytes, ...}``), only the requested fields; a member that does
    not decode to its field's type is a :class:`ShardError` naming the tar, key and field."""
    wanted = None if fields is None else set(fields) | {"meta"}
    sample: dict[str, Any] = {"__key__": raw["__key__"]}
    for member, data in raw.items():
        if member.startswith("__"):
            continue
        name = member.rsplit(".", 1)[0]
        if wanted is None or name in wanted:
            sample[name] = _decode_member(raw, name, data)
    _check_members(raw, sample.get("meta"))
    return sample


def _check_members(raw: dict[str, Any], meta: Any) -> None:
    """Raise :class:`ShardError` unless the sample holds every field its ``meta.has`` flags (and ``past``): a zeroed
    or damaged tar header ends the tar's stream in the middle of a sample, which comes out short of its last
    fields, with no error from tarfile."""
    where = f"{raw.get('__url__', 'shard')}: sample {raw['__key__']!r}"
    if not isinstance(meta, dict) or not isinstance(meta.get("has"), dict):
        raise ShardError(f"{where}: no meta.json with its 'has' flags (a damaged tar); {_REDO}")
    present = {member.rsplit(".", 1)[0] for member in raw if not member.startswith("__")}
    flagged = [name for name, flag in meta["has"].items() if flag]
    missing = [name for name in (*REQUIRED_FIELDS, *flagged) if name not in present]
    if missing:
        raise ShardError(f"{where}: field {missing[0]!r} is missing from the tar (a damaged header ends it); {_REDO}")


def _decode_member(raw: dict[str, Any], name: str, data: bytes) -> Any:
    where = f"{raw.get('__url__', 'shard')}: sample {raw['__key__']!r}, field {name!r}"
    try:
        spec = field_spec(name)
        value = decode_field(name, data)
    except KeyError:
        raise ShardError(f"{where}: not a schema v1 field; {_REDO}") from None
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError, TokenError) as err:
        # .npz: a zip of deflated .npy, whose damaged flags or method zipfile refuses as NotImplementedError; a .npy
        # header numpy cannot parse is retried as Python 2's, whose tokenizer raises TokenError
        raise ShardError(f"{where}: cannot be decoded as .{spec.ext} ({err}); {_REDO}") from None
    if spec.ext == "npy" and spec.dtype is not None and value.dtype != np.dtype(spec.dtype):
        raise ShardError(f"{where}: dtype {value.dtype}, but schema v1 stores {spec.dtype}; {_REDO}")
    return value


def read_samples(path: str | Path, fields: Iterable[str] | None = None) -> Iterator[dict[str, Any]]:
    """Yield decoded samples from a converted folder or shard(s), in shard order; ``fields`` limits decoding to those
    fields (``meta`` is always decoded). Every sample comes out in every process: no splitting over ranks or workers.
    In a converted folder every tar must yield what the manifest lists for it."""
    fields = None if fields is None else tuple(fields)
    listed = listed_keys(path)
    shards = shard_paths(path)
    if listed is not None and Path(path).is_dir():
        check_listed_shards(listed)
    reader = TarSamples(fields)
    raws = (raw for shard in shards for raw in reader.read(shard))
    for raw in raws if listed is None else ManifestCheck(listed)(raws):
        yield decode_sample(raw, fields)


def read_part(
    shard: str, keys: Sequence[str], fields: Iterable[str] | None = None, offset: int = 0
) -> list[dict[str, Any]]:
    """Decode the samples ``keys`` (consecutive samples of one tar of a converted folder, the first at byte
    ``offset``: :func:`sample_offsets`), in tar order: one job of a parallel reader (``score --workers``), which
    hands a big tar out in parts, each read from its offset to its last sample. Members of fields nobody decodes are
    listed for :func:`decode_sample`'s completeness check, not read."""
    asked = set(keys)
    raws: dict[str, dict[str, Any]] = {}
    for raw in TarSamples(fields).read(shard, offset):
        if raw["__key__"] in asked:
            raws[raw["__key__"]] = raw
        elif len(raws) == len(asked):  # past the last sample asked for
            break
    if len(raws) < len(asked):
        missing = next(key for key in keys if key not in raws)
        raise ShardError(f"{shard}: sample {missing!r}, which the manifest lists in it, is not in the tar; {_REDO}")
    return [decode_sample(raw, fields) for raw in raws.values()]


def sample_offsets(shard: str) -> dict[str, int]:
    """The byte offset of each sample's first member in ``shard`` (where :func:`read_part` starts a part): one walk
    over the headers, seeking past the data."""
    offsets: dict[str, int] = {}
    try:
        with tarfile.open(shard, "r:") as tar:
            for member in tar:
                offsets.setdefault(member.name.partition(".")[0], member.offset)
    except tarfile.TarError as err:
        raise ShardError(f"{shard}: cannot be read as a tar ({err}); {_REDO}") from None
    return offsets


def shard_parts(rows: Iterable[Mapping[str, Any]], size: int) -> list[tuple[str, list[str], int]]:
    """Manifest rows (``shard``, ``key``) -> parts of up to ``size`` consecutive samples of one tar, each with the
    offset :func:`read_part` starts at: the jobs of a parallel reader. A tar read in one part is read from its start,
    sparing the walk over its headers."""
    parts = []
    for shard, keys in keys_by_shard((row["shard"], row["key"]) for row in rows).items():
        offsets = sample_offsets(shard) if len(keys) > size else {keys[0]: 0}
        parts += [(shard, keys[start : start + size], offsets[keys[start]]) for start in range(0, len(keys), size)]
    return parts


def write_manifest(folder: Path, table: pa.Table) -> Path:
    """``folder``'s manifest: one row per sample (key, shard, dataset, split, log, tags, ``has_*`` flags), with a CRC32
    of every data page, so a damaged manifest is an error naming it, not samples listed in another shard."""
    return write_parquet(folder / MANIFEST, table)


def load_manifest(path: str | Path, columns: Sequence[str] | None = None, required: Sequence[str] = ()) -> pa.Table:
    """The manifest table of a converted folder (or the parquet file itself): one row per sample, no blobs.
    ``columns`` keeps only those; they and ``required`` must be there. Manifests written before the page CRCs carry
    none and read as before; any unreadable one is a :class:`ShardError` naming it."""
    path = Path(path)
    file = path / MANIFEST if path.is_dir() else path
    if path.is_dir() and not file.is_file():
        raise ShardError(f"{path} holds no {MANIFEST}: not a converted folder (or its conversion did not finish); "
                         "give a folder `lead-s2r convert` wrote")  # fmt: skip
    try:
        table = read_parquet(file)
        table.validate(full=True)  # parquet does not check that strings are UTF-8; reading them would raise later
    except (pa.ArrowException, OSError, ValueError) as err:  # ArrowInvalid (not parquet), OSError (missing, CRC)
        raise ShardError(f"{file}: cannot be read as a manifest ({_first_line(err)}); {_REDO}") from None
    absent = [name for name in (*(columns or ()), *required) if name not in table.column_names]
    if absent and not len(table):
        raise ShardError(f"{file} lists no sample: the conversion wrote none; see the errors.jsonl beside it")
    if absent:
        raise ShardError(f"{file}: no column {absent[0]!r}; {_REDO}")
    return table if columns is None else table.select(list(columns))


def load_info(path: str | Path) -> dict[str, Any]:
    """``info.json`` of a converted folder; missing, undecodable or not a JSON object is a :class:`ShardError`."""
    file = Path(path) / INFO
    try:
        info = json.loads(file.read_bytes())
    except OSError as err:
        raise ShardError(f"{file}: cannot be read ({err.strerror or err}); {_REDO}") from None
    except ValueError as err:  # JSONDecodeError, UnicodeDecodeError
        raise ShardError(f"{file}: not valid JSON ({_first_line(err)}); {_REDO}") from None
    if not isinstance(info, dict):
        raise ShardError(f"{file}: expected a JSON object, got {type(info).__name__}; {_REDO}")
    return info


def value_range(values: np.ndarray) -> dict[str, float] | None:
    """min, max and mean of a manifest column's finite ``values`` (None: none is finite), as info.json's statistics
    and ``inspect`` report them."""
    values = values[np.isfinite(values)]
    if not len(values):
        return None
    return {"min": float(values.min()), "max": float(values.max()), "mean": float(values.mean())}


def _first_line(err: Exception) -> str:
    """The first line of a library's message (Arrow's run over several)."""
    return (str(err).strip().splitlines() or [type(err).__name__])[0]
