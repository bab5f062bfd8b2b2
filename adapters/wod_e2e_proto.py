"""Our own minimal protobuf schema for WOD-E2E ``E2EDFrame`` records, built at import time without protoc.

Only the fields the adapter reads are declared, with Waymo's documented field numbers (proto2, as upstream);
everything else in a record (poses, velocities, map, labels) stays an unknown field and is ignored. Enums
(camera name, intent) are declared as int32: the wire format is the same, and a value outside the known range
is kept instead of being silently dropped to its default. A private descriptor pool keeps these message names
from clashing with an installed waymo-open-dataset package.
"""

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import Message

_PACKAGE = "lead_s2r.wod_e2e"
_F = descriptor_pb2.FieldDescriptorProto


def _field(name: str, number: int, kind: int, repeated: bool = False, message: str = "", packed: bool = False):
    return (name, number, kind, repeated, message, packed)


_MESSAGES: dict[str, list[tuple]] = {
    "Transform": [_field("transform", 1, _F.TYPE_DOUBLE, repeated=True)],
    "CameraCalibration": [
        _field("name", 1, _F.TYPE_INT32),
        _field("intrinsic", 2, _F.TYPE_DOUBLE, repeated=True),
        _field("extrinsic", 3, _F.TYPE_MESSAGE, message="Transform"),
        _field("width", 4, _F.TYPE_INT32),
        _field("height", 5, _F.TYPE_INT32),
    ],
    "Context": [
        _field("name", 1, _F.TYPE_STRING),
        _field("camera_calibrations", 2, _F.TYPE_MESSAGE, repeated=True, message="CameraCalibration"),
    ],
    "CameraImage": [_field("name", 1, _F.TYPE_INT32), _field("image", 2, _F.TYPE_BYTES)],
    "Frame": [
        _field("context", 1, _F.TYPE_MESSAGE, message="Context"),
        _field("timestamp_micros", 2, _F.TYPE_INT64),
        _field("images", 4, _F.TYPE_MESSAGE, repeated=True, message="CameraImage"),
    ],
    "EgoTrajectoryStates": [
        *(
            _field(name, number, _F.TYPE_FLOAT, repeated=True, packed=True)
            for number, name in enumerate(("pos_x", "pos_y", "pos_z", "vel_x", "vel_y", "accel_x", "accel_y"), 1)
        ),
        _field("preference_score", 8, _F.TYPE_FLOAT),
    ],
    "E2EDFrame": [
        _field("frame", 1, _F.TYPE_MESSAGE, message="Frame"),
        _field("future_states", 5, _F.TYPE_MESSAGE, message="EgoTrajectoryStates"),
        _field("past_states", 6, _F.TYPE_MESSAGE, message="EgoTrajectoryStates"),
        _field("intent", 7, _F.TYPE_INT32),
        _field("preference_trajectories", 8, _F.TYPE_MESSAGE, repeated=True, message="EgoTrajectoryStates"),
    ],
}


def _file_descriptor() -> descriptor_pb2.FileDescriptorProto:
    proto = descriptor_pb2.FileDescriptorProto(name="lead_s2r/wod_e2e.proto", package=_PACKAGE, syntax="proto2")
    for message_name, fields in _MESSAGES.items():
        message = proto.message_type.add(name=message_name)
        for name, number, kind, repeated, type_name, packed in fields:
            field = message.field.add(name=name, number=number, type=kind)
            field.label = _F.LABEL_REPEATED if repeated else _F.LABEL_OPTIONAL
            if type_name:
                field.type_name = f".{_PACKAGE}.{type_name}"
            if packed:
                field.options.packed = True
    return proto


_POOL = descriptor_pool.DescriptorPool()
_POOL.Add(_file_descriptor())


def _message_class(name: str) -> type[Message]:
    return message_factory.GetMessageClass(_POOL.FindMessageTypeByName(f"{_PACKAGE}.{name}"))


E2EDFrame = _message_class("E2EDFrame")
EgoTrajectoryStates = _message_class("EgoTrajectoryStates")
