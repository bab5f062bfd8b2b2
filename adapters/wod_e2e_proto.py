"""Our own minimal protobuf schema for WOD-E2E ``E2EDFrame`` records, built at import time without protoc.

Only the fields the adapter reads are declared, with Waymo's documented field numbers (proto2, as upstream);
everything else in a record (poses, velocities, map, labels) stays an unknown field and is ignored. Enums
(camera name, intent) are declared as int32: the wire format is the same, and a value outside the known range
is kept instead of being silently dropped to its default. A private descriptor pool keeps these message names
from clashing with an installed waymo-open-dataset package.
"""

from typing import NamedTuple

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import Message

_PACKAGE = "lead_s2r.wod_e2e"
_F = descriptor_pb2.FieldDescriptorProto


class _Field(NamedTuple):
    name: str
    number: int
    kind: int
    repeated: bool = False
    message: str = ""
    packed: bool = False


_MESSAGES: dict[str, list[_Field]] = {
    "Transform": [_Field("transform", 1, _F.TYPE_DOUBLE, repeated=True)],
    "CameraCalibration": [
        _Field("name", 1, _F.TYPE_INT32),
        _Field("intrinsic", 2, _F.TYPE_DOUBLE, repeated=True),
        _Field("extrinsic", 3, _F.TYPE_MESSAGE, message="Transform"),
        _Field("width", 4, _F.TYPE_INT32),
        _Field("height", 5, _F.TYPE_INT32),
    ],
    "Context": [
        _Field("name", 1, _F.TYPE_STRING),
        _Field("camera_calibrations", 2, _F.TYPE_MESSAGE, repeated=True, message="CameraCalibration"),
    ],
    "CameraImage": [_Field("name", 1, _F.TYPE_INT32), _Field("image", 2, _F.TYPE_BYTES)],
    "Frame": [
        _Field("context", 1, _F.TYPE_MESSAGE, message="Context"),
        _Field("timestamp_micros", 2, _F.TYPE_INT64),
        _Field("images", 4, _F.TYPE_MESSAGE, repeated=True, message="CameraImage"),
    ],
    "EgoTrajectoryStates": [
        *(
            _Field(name, number, _F.TYPE_FLOAT, repeated=True, packed=True)
            for number, name in enumerate(("pos_x", "pos_y", "pos_z", "vel_x", "vel_y", "accel_x", "accel_y"), 1)
        ),
        _Field("preference_score", 8, _F.TYPE_FLOAT),
    ],
    "E2EDFrame": [
        _Field("frame", 1, _F.TYPE_MESSAGE, message="Frame"),
        _Field("future_states", 5, _F.TYPE_MESSAGE, message="EgoTrajectoryStates"),
        _Field("past_states", 6, _F.TYPE_MESSAGE, message="EgoTrajectoryStates"),
        _Field("intent", 7, _F.TYPE_INT32),
        _Field("preference_trajectories", 8, _F.TYPE_MESSAGE, repeated=True, message="EgoTrajectoryStates"),
    ],
}


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    proto = descriptor_pb2.FileDescriptorProto(name="lead_s2r/wod_e2e.proto", package=_PACKAGE, syntax="proto2")
    for message_name, fields in _MESSAGES.items():
        message = proto.message_type.add(name=message_name)
        for spec in fields:
            field = message.field.add(name=spec.name, number=spec.number, type=spec.kind)
            field.label = _F.LABEL_REPEATED if spec.repeated else _F.LABEL_OPTIONAL
            if spec.message:
                field.type_name = f".{_PACKAGE}.{spec.message}"
            if spec.packed:
                field.options.packed = True
    return proto


_POOL = descriptor_pool.DescriptorPool()
_POOL.Add(_file_descriptor())


def _message_class(name: str) -> type[Message]:
    return message_factory.GetMessageClass(_POOL.FindMessageTypeByName(f"{_PACKAGE}.{name}"))


E2EDFrame = _message_class("E2EDFrame")
EgoTrajectoryStates = _message_class("EgoTrajectoryStates")
