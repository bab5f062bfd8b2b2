"""Putting a written file or folder in place in one step: every writer of ours goes through here, and nothing
else renames (tests/test_owners.py checks).

Why: a crash, a full disk or Ctrl-C in the middle of a write must leave the old file or the new one, never a torn
file that passes for a result (a scores.parquet without its rows, a manifest cut short). So each write goes to a
temporary name beside its target (same folder, so the rename stays on one file system and is atomic on POSIX) that
is unique per process and thread, since scoring workers may write the same cache entry at once; the temporary is
removed whatever happens.
Parquet files we read back (predictions, scores, manifests) carry a CRC32 per data page, checked on reading: nothing
else guards a value. pyarrow is imported there only (0.2 s of a conversion worker's start-up, which writes shards).
"""

import base64
import os
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import pyarrow as pa


def write_atomically(path: Path, write: Callable[[Path], object]) -> Path:
    """Run ``write(temporary)`` beside ``path``, then rename the result to ``path``; nothing is left if it fails."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.{os.getpid()}-{threading.get_ident()}.partial")
    try:
        write(partial)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return path


def write_text(path: Path, text: str) -> Path:
    """:func:`write_atomically` for a UTF-8 text file."""
    return write_atomically(path, lambda partial: partial.write_text(text, encoding="utf-8"))


def write_bytes(path: Path, data: bytes) -> Path:
    """:func:`write_atomically` for bytes."""
    return write_atomically(path, lambda partial: partial.write_bytes(data))


def move_into_place(partial: Path, path: Path) -> None:
    """Give a file written piece by piece under a temporary name (a shard being filled) its final name."""
    os.replace(partial, path)


@contextmanager
def staged_folder(out: Path) -> Iterator[Path]:
    """A new sibling of ``out`` to fill (mode 0755: mkdtemp's 0700 would hide a site from a web server), which
    becomes ``out`` when the block ends (an older ``out`` is removed only once the new one is in place) and is
    removed when the block fails."""
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    staging.chmod(0o755)
    try:
        yield staging
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}-old-", dir=out.parent))
        os.replace(out, old / out.name)
        os.replace(staging, out)
        shutil.rmtree(old)
    else:
        os.replace(staging, out)


def write_parquet(path: Path, table: "pa.Table") -> Path:
    """:func:`write_atomically` for a parquet table, with a CRC32 of every data page (:func:`read_parquet` checks
    them)."""
    import pyarrow.parquet as pq

    return write_atomically(path, lambda partial: pq.write_table(table, partial, write_page_checksum=True))


def read_parquet(path: str | Path) -> "pa.Table":
    """A parquet table, checked as far as the file allows: the CRC of every page that carries one, then what no
    checksum covers: the row counts of the footer and of its row groups (a flipped bit there drops rows unseen), and
    the columns' names and types against the Arrow schema pyarrow stores beside them. Raises OSError or
    ArrowException for a damaged file (ArrowInvalid for counts or columns that disagree), ValueError for a name that
    is no longer UTF-8 or a stored schema that is no longer base64."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pq.read_table(path, page_checksum_verification=True)
    metadata = pq.read_metadata(path)
    grouped = sum(metadata.row_group(i).num_rows for i in range(metadata.num_row_groups))
    if not metadata.num_rows == grouped == table.num_rows:
        raise pa.ArrowInvalid(f"its footer counts {metadata.num_rows} rows, its row groups {grouped}")
    stored = (metadata.metadata or {}).get(b"ARROW:schema")
    if stored is not None:
        written = pa.ipc.read_schema(pa.py_buffer(base64.b64decode(stored, validate=True)))
        if table.schema.names != written.names:
            raise pa.ArrowInvalid(f"its footer names the columns {table.schema.names}, written as {written.names}")
        retyped = [f"{a.name}: {a.type}" for a, b in zip(table.schema, written, strict=True) if not a.equals(b)]
        if retyped:
            raise pa.ArrowInvalid(f"its footer types the columns {retyped} otherwise than they were written")
    return table
