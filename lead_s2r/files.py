"""Putting a written file or folder in place in one step: every writer of ours goes through here, and nothing
else renames (tests/test_owners.py checks).

Why: a crash, a full disk or Ctrl-C in the middle of a write must leave the old file or the new one, never a torn
file that passes for a result (a scores.parquet without its rows, a manifest cut short). So each write goes to a
temporary name beside its target (same folder, so the rename stays on one file system and is atomic on POSIX) that
is unique per process and thread, since scoring workers may write the same cache entry at once; the temporary is
removed whatever happens.
"""

import os
import shutil
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path


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


def replace_folder(staging: Path, out: Path) -> None:
    """Move a finished folder to ``out``; an older folder there is removed only once the new one is in place."""
    if out.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out.name}-old-", dir=out.parent))
        os.replace(out, old / out.name)
        os.replace(staging, out)
        shutil.rmtree(old)
    else:
        os.replace(staging, out)
