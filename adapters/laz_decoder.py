"""LAZ decoding in a helper process, so that a damaged file ends one log, not the conversion.

lazrs aborts its whole process on some damaged files (a corrupt chunk table asks it for 28 GB: "memory allocation
failed", SIGABRT), which no ``except`` can catch. Each process that reads LAZ therefore keeps one helper,
``python -m lead_s2r_adapters.laz_decoder``, started on first use and again after it dies: a plain subprocess, so
no multiprocessing start method re-imports the caller's main module. It ends when its stdin closes (its parent
ended). Protocol: one JSON-quoted path a line in; per path, one status byte (``P`` points, ``E`` error), an 8-byte
little-endian length and that many bytes out: an ``.npy`` of (N, 4) float64 x, y, z, time, or a UTF-8 message.
A point cloud crosses the pipe in about a millisecond.
"""

import io
import json
import struct
import subprocess
import sys
from pathlib import Path
from typing import BinaryIO

import numpy as np

_HEADER = struct.Struct("<cQ")


class LazDecodeError(Exception):
    """A LAZ file the decoder refused or died on; the message says why, the caller names the file."""


def _decode(path: Path) -> np.ndarray:
    """(N, 4) float64 x, y, z, time of one LEAD ``.laz`` file, decoded in this process."""
    import laspy

    las = laspy.read(str(path))
    if "time" not in set(las.point_format.extra_dimension_names):
        raise LazDecodeError("LAS file has no extra dimension 'time'")
    columns = [np.asarray(las.x), np.asarray(las.y), np.asarray(las.z), np.asarray(las["time"])]
    return np.column_stack(columns).astype(np.float64)


def serve(requests: BinaryIO, replies: BinaryIO) -> None:
    """The helper's loop: decode each requested path and reply, until ``requests`` ends."""
    import laspy
    import lazrs

    # What laspy and lazrs raise for a damaged file: format errors, short reads, bad header values.
    damaged = (laspy.errors.LaspyException, lazrs.LazrsError, LazDecodeError, OSError, EOFError, ValueError)
    for line in requests:
        try:
            buffer = io.BytesIO()
            np.save(buffer, _decode(Path(json.loads(line))), allow_pickle=False)
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
    def decode(cls, path: Path) -> np.ndarray:
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
            process.stdin.write(json.dumps(str(path)).encode() + b"\n")
            process.stdin.flush()
            status, size = _HEADER.unpack(_read(process.stdout, _HEADER.size))
            payload = _read(process.stdout, size)
        except (BrokenPipeError, EOFError):
            cls.process = None
            raise LazDecodeError(f"the LAZ decoder died on it (exit status {process.wait()})") from None
        if status != b"P":
            raise LazDecodeError(payload.decode(errors="replace"))
        return np.load(io.BytesIO(payload), allow_pickle=False)


def _read(stream: BinaryIO, size: int) -> bytes:
    data = stream.read(size)
    if len(data) != size:
        raise EOFError
    return data


def decode(path: Path) -> np.ndarray:
    """(N, 4) float64 x, y, z, time of one LEAD ``.laz`` file, decoded in the helper process; a file the decoder
    refuses or dies on is a :class:`LazDecodeError`."""
    return _Helper.decode(path)


if __name__ == "__main__":
    serve(sys.stdin.buffer, sys.stdout.buffer)
