"""LAZ decoding in a helper process, so that a damaged file ends one log, not the conversion.

lazrs aborts its whole process on some damaged files (a corrupt chunk table asks it for 28 GB: "memory allocation
failed", SIGABRT), which no ``except`` can catch. Each process that reads LAZ therefore keeps one helper,
``python -m lead_s2r_adapters.laz_decoder``, started on first use and again after it dies: a plain subprocess, so
no multiprocessing start method re-imports the caller's main module. It ends when its stdin closes (its parent
ended). Protocol: one JSON request a line in, ``[path, every]``; per request, one status byte (``P`` points, ``E``
error), an 8-byte little-endian length and that many bytes out: an ``.npy`` of (N, 4) float64 x, y, z, time (LEAD's
files), or with ``every`` an ``.npz`` of x, y, z and every extra dimension by its name (123D's LiDAR payloads, which
the caller writes to a file first), or a UTF-8 message. A point cloud crosses the pipe in about a millisecond.
"""

import io
import json
import select
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

_HEADER = struct.Struct("<cQ")
#: Raw point bytes per compressed byte a LAZ file may claim (LEAD's files: about 6).
MAX_COMPRESSION = 100
#: Seconds the helper may take for one file (LEAD's take about 0.05 s) before it is killed and the file refused.
TIMEOUT_S = 60.0


class LazDecodeError(Exception):
    """A LAZ file the decoder refused or died on; the message says why, the caller names the file."""


def _read_las(path: Path) -> Any:
    """The points of one LAZ file, decoded in this process. The header's point count is held against the file's size
    first: a damaged count makes the decoder allocate and fill gigabytes for minutes (LAZ packs a point into no less
    than a hundredth of its record, LEAD's about a sixth)."""
    import laspy

    with laspy.open(str(path)) as reader:
        header, size = reader.header, path.stat().st_size
        if header.point_count * header.point_format.size > MAX_COMPRESSION * size:
            raise LazDecodeError(f"the header claims {header.point_count} points, more than {size} bytes can hold")
        return reader.read()


def _decode(path: Path) -> np.ndarray:
    """(N, 4) float64 x, y, z, time of one LEAD ``.laz`` file, decoded in this process."""
    las = _read_las(path)
    if "time" not in set(las.point_format.extra_dimension_names):
        raise LazDecodeError("LAS file has no extra dimension 'time'")
    columns = [np.asarray(las.x), np.asarray(las.y), np.asarray(las.z), np.asarray(las["time"])]
    return np.column_stack(columns).astype(np.float64)


def _decode_every(path: Path) -> dict[str, np.ndarray]:
    """x, y, z (float64) and every extra dimension of one LAZ file, decoded in this process."""
    las = _read_las(path)
    columns = {"x": np.asarray(las.x), "y": np.asarray(las.y), "z": np.asarray(las.z)}
    return columns | {name: np.asarray(las[name]) for name in las.point_format.extra_dimension_names}


def serve(requests: BinaryIO, replies: BinaryIO) -> None:
    """The helper's loop: decode each requested path and reply, until ``requests`` ends."""
    import laspy
    import lazrs

    # What laspy and lazrs raise for a damaged file: format errors, short reads, bad header values.
    damaged = (laspy.errors.LaspyException, lazrs.LazrsError, LazDecodeError, OSError, EOFError, ValueError)
    for line in requests:
        try:
            path, every = json.loads(line)
            buffer = io.BytesIO()
            if every:
                np.savez(buffer, **_decode_every(Path(path)))
            else:
                np.save(buffer, _decode(Path(path)), allow_pickle=False)
            status, payload = b"P", buffer.getvalue()
        except damaged as err:
            status, payload = b"E", f"{type(err).__name__}: {err}".encode()
        except MemoryError:
            status, payload = b"E", b"MemoryError: the header asks for more points than fit in memory"
        replies.write(_HEADER.pack(status, len(payload)) + payload)
        replies.flush()


class _Helper:
    """The helper process of this process, (re)started when needed."""

    process: subprocess.Popen | None = None

    @classmethod
    def decode(cls, path: Path, every: bool) -> bytes:
        """The helper's reply to ``[path, every]`` (see the module docstring)."""
        if cls.process is None or cls.process.poll() is not None:
            cls.process = subprocess.Popen(
                [sys.executable, "-m", __name__],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,  # a dying decoder's backtrace is not the user's business
            )
        process = cls.process
        assert process.stdin is not None and process.stdout is not None
        try:
            process.stdin.write(json.dumps([str(path), every]).encode() + b"\n")
            process.stdin.flush()
            if not select.select([process.stdout], [], [], TIMEOUT_S)[0]:
                process.kill()
                raise TimeoutError
            status, size = _HEADER.unpack(_read(process.stdout, _HEADER.size))
            payload = _read(process.stdout, size)
        except (BrokenPipeError, EOFError):
            cls.process = None
            raise LazDecodeError(f"the LAZ decoder died on it (exit status {process.wait()})") from None
        except TimeoutError:
            cls.process = None
            process.wait()
            raise LazDecodeError(f"the LAZ decoder took over {TIMEOUT_S:g} s on it and was stopped") from None
        if status != b"P":
            raise LazDecodeError(payload.decode(errors="replace"))
        return payload


def _read(stream: BinaryIO, size: int) -> bytes:
    data = stream.read(size)
    if len(data) != size:
        raise EOFError
    return data


def decode(path: Path) -> np.ndarray:
    """(N, 4) float64 x, y, z, time of one LEAD ``.laz`` file, decoded in the helper process; a file the decoder
    refuses or dies on is a :class:`LazDecodeError`."""
    return np.load(io.BytesIO(_Helper.decode(path, every=False)), allow_pickle=False)


def decode_every(path: Path) -> dict[str, np.ndarray]:
    """x, y, z and every extra dimension (by its LAS name) of one LAZ file, decoded in the helper process; a file
    the decoder refuses or dies on is a :class:`LazDecodeError`."""
    with np.load(io.BytesIO(_Helper.decode(path, every=True)), allow_pickle=False) as columns:
        return {name: columns[name] for name in columns.files}


if __name__ == "__main__":
    serve(sys.stdin.buffer, sys.stdout.buffer)
