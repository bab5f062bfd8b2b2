"""Protobuf message classes from a few declared fields, built at import time without protoc or generated code.

WOD-E2E's records and its submission protos are proto2 messages of Waymo's; we declare only the fields we read or
write, with Waymo's field numbers, instead of vendoring their ``*_pb2`` modules (which need TensorFlow's package
to import). Enums are declared as int32: the wire format is the same, and a value outside the known range is kept
instead of being silently dropped to its default. Each schema gets a private descriptor pool, so its message names
never clash with an installed waymo-open-dataset package. Needs ``protobuf`` (the ``wod`` extra).
"""

from typing import NamedTuple

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import Message

#: Field types and labels (``FieldDescriptorProto.TYPE_FLOAT``, ...).
F = descriptor_pb2.FieldDescriptorProto


class Field(NamedTuple):
    name: str
    number: int
    kind: int
    repeated: bool = False
    message: str = ""  # the message type of a TYPE_MESSAGE field, by its name in the same schema
    packed: bool = False


def message_classes(file_name: str, package: str, messages: dict[str, list[Field]]) -> dict[str, type[Message]]:
    """One class per declared message, in a pool of its own; ``file_name`` is the descriptor's (unused) path."""
    proto = descriptor_pb2.FileDescriptorProto(name=file_name, package=package, syntax="proto2")
    for message_name, fields in messages.items():
        message = proto.message_type.add(name=message_name)
        for spec in fields:
            field = message.field.add(name=spec.name, number=spec.number, type=spec.kind)
            field.label = F.LABEL_REPEATED if spec.repeated else F.LABEL_OPTIONAL
            if spec.message:
                field.type_name = f".{package}.{spec.message}"
            if spec.packed:
                field.options.packed = True
    pool = descriptor_pool.DescriptorPool()
    pool.Add(proto)
    return {name: message_factory.GetMessageClass(pool.FindMessageTypeByName(f"{package}.{name}")) for name in messages}
