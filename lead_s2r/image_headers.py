"""What an encoded image's header says without decoding it: its size (JPEG, PNG).

Two readers need the size before (or instead of) a decode: the NAVSIM adapter checks each camera against its
calibration, and the training transform plans a sample's camera layout and decode path from it
(:mod:`lead_s2r.data.camera_input`). Reading the header costs a few microseconds; opening the image with Pillow to
ask costs 20x that.
"""

import numpy as np

#: Start-of-frame markers (baseline, progressive, lossless, arithmetic): the segment that holds the frame size.
_START_OF_FRAME = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def jpeg_size(encoded: bytes | memoryview | np.ndarray) -> tuple[int, int] | None:
    """(width, height) from a JPEG's frame header; None where ``encoded`` (bytes or a uint8 buffer) is not a JPEG
    with one."""
    data = memoryview(encoded).cast("B")
    i = 2
    while data[:2] == b"\xff\xd8" and i + 9 <= len(data):
        if data[i] != 0xFF:
            break
        marker = data[i + 1]
        if marker == 0xFF or 0xD0 <= marker <= 0xD7 or marker == 0x01:
            i += 1 if marker == 0xFF else 2
            continue
        if marker in _START_OF_FRAME:
            return int.from_bytes(data[i + 7 : i + 9], "big"), int.from_bytes(data[i + 5 : i + 7], "big")
        i += 2 + int.from_bytes(data[i + 2 : i + 4], "big")
    return None


def png_size(encoded: bytes | memoryview | np.ndarray) -> tuple[int, int] | None:
    """(width, height) from a PNG's IHDR chunk; None where ``encoded`` is not a PNG."""
    data = memoryview(encoded).cast("B")
    if len(data) < 24 or data[:8] != b"\x89PNG\r\n\x1a\n" or data[12:16] != b"IHDR":
        return None
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
