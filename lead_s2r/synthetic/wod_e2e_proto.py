"""Writer-side protobuf wire encoding of WOD-E2E ``E2EDFrame`` records, by hand.

Deliberately independent of the adapter's reader (which parses with the ``protobuf`` runtime): if both sides
agreed on a wrong field number or wire type, a shared schema would hide it; two implementations will not.
Field numbers follow Waymo's ``end_to_end_driving_data.proto`` and ``dataset.proto`` (proto2). Some fields the
reader ignores (poses, rolling shutter direction) are written too, so it must tolerate unknown fields.
"""

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

_VARINT, _FIXED64, _LEN, _FIXED32 = 0, 1, 2, 5


def _varint(value: int) -> bytes:
    value &= (1 << 64) - 1  # negative int32/int64 are encoded as 10-byte two's complement
    out = bytearray()
    while value > 0x7F:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    return bytes(out) + bytes([value])


def _tag(number: int, wire_type: int) -> bytes:
    return _varint(number << 3 | wire_type)


def int_field(number: int, value: int) -> bytes:
    return _tag(number, _VARINT) + _varint(value)


def bytes_field(number: int, value: bytes) -> bytes:
    """A length-delimited field: bytes, strings and embedded messages alike."""
    return _tag(number, _LEN) + _varint(len(value)) + value


def float_field(number: int, value: float) -> bytes:
    return _tag(number, _FIXED32) + struct.pack("<f", value)


def repeated_doubles(number: int, values: Iterable[float]) -> bytes:
    """proto2 ``repeated double`` without ``[packed=true]``: one tagged fixed64 per element."""
    return b"".join(_tag(number, _FIXED64) + struct.pack("<d", v) for v in values)


def packed_floats(number: int, values: Sequence[float]) -> bytes:
    return bytes_field(number, struct.pack(f"<{len(values)}f", *values))


def transform(matrix: Sequence[float]) -> bytes:
    """``Transform{transform = 1}``: a row-major 4x4 matrix."""
    return repeated_doubles(1, matrix)


def camera_image(name: int, jpeg: bytes) -> bytes:
    """``CameraImage``: name = 1, image = 2, plus the identity pose = 3 that E2E records carry."""
    identity = [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
    return int_field(1, name) + bytes_field(2, jpeg) + bytes_field(3, transform(identity))


def camera_calibration(name: int, intrinsic: Sequence[float], extrinsic: Sequence[float], width: int, height: int):
    """``CameraCalibration``: name 1, intrinsic 2, extrinsic 3, width 4, height 5, rolling shutter direction 6."""
    fields = int_field(1, name) + repeated_doubles(2, intrinsic) + bytes_field(3, transform(extrinsic))
    return fields + int_field(4, width) + int_field(5, height) + int_field(6, 2)


@dataclass
class States:
    """``EgoTrajectoryStates`` columns; None = not written (e.g. past has no pos_z, raters only x and y)."""

    pos_x: Sequence[float]
    pos_y: Sequence[float]
    pos_z: Sequence[float] | None = None
    vel_x: Sequence[float] | None = None
    vel_y: Sequence[float] | None = None
    accel_x: Sequence[float] | None = None
    accel_y: Sequence[float] | None = None
    preference_score: float | None = None

    def encode(self) -> bytes:
        columns = (self.pos_x, self.pos_y, self.pos_z, self.vel_x, self.vel_y, self.accel_x, self.accel_y)
        out = b"".join(packed_floats(number, col) for number, col in enumerate(columns, 1) if col is not None)
        if self.preference_score is not None:
            out += float_field(8, self.preference_score)
        return out


def e2ed_frame(
    name: str,
    images: Sequence[bytes],
    calibrations: Sequence[bytes],
    past: States,
    future: States | None,
    intent: int,
    preferences: Sequence[States] = (),
) -> bytes:
    """``E2EDFrame{frame = 1, future_states = 5, past_states = 6, intent = 7, preference_trajectories = 8}``; the
    frame's ``timestamp_micros`` is 0, as in the real data."""
    context = bytes_field(1, name.encode()) + b"".join(bytes_field(2, c) for c in calibrations)
    frame = bytes_field(1, context) + int_field(2, 0) + b"".join(bytes_field(4, i) for i in images)
    out = bytes_field(1, frame)
    if future is not None:
        out += bytes_field(5, future.encode())
    out += bytes_field(6, past.encode()) + int_field(7, intent)
    return out + b"".join(bytes_field(8, p.encode()) for p in preferences)
