"""Our own minimal protobuf schema for WOD-E2E ``E2EDFrame`` records (built by :mod:`lead_s2r.formats.proto_schema`).

Only the fields the adapter reads are declared, with Waymo's documented field numbers (proto2, as upstream);
everything else in a record (poses, velocities, map, labels) stays an unknown field and is ignored. Enums
(camera name, intent) are declared as int32, so an out-of-range value is kept rather than dropped.
"""

from lead_s2r.formats.proto_schema import F, Field, message_classes

_MESSAGES: dict[str, list[Field]] = {
    "Transform": [Field("transform", 1, F.TYPE_DOUBLE, repeated=True)],
    "CameraCalibration": [
        Field("name", 1, F.TYPE_INT32),
        Field("intrinsic", 2, F.TYPE_DOUBLE, repeated=True),
        Field("extrinsic", 3, F.TYPE_MESSAGE, message="Transform"),
        Field("width", 4, F.TYPE_INT32),
        Field("height", 5, F.TYPE_INT32),
    ],
    "Context": [
        Field("name", 1, F.TYPE_STRING),
        Field("camera_calibrations", 2, F.TYPE_MESSAGE, repeated=True, message="CameraCalibration"),
    ],
    "CameraImage": [Field("name", 1, F.TYPE_INT32), Field("image", 2, F.TYPE_BYTES)],
    "Frame": [
        Field("context", 1, F.TYPE_MESSAGE, message="Context"),
        Field("timestamp_micros", 2, F.TYPE_INT64),
        Field("images", 4, F.TYPE_MESSAGE, repeated=True, message="CameraImage"),
    ],
    "EgoTrajectoryStates": [
        *(
            Field(name, number, F.TYPE_FLOAT, repeated=True, packed=True)
            for number, name in enumerate(("pos_x", "pos_y", "pos_z", "vel_x", "vel_y", "accel_x", "accel_y"), 1)
        ),
        Field("preference_score", 8, F.TYPE_FLOAT),
    ],
    "E2EDFrame": [
        Field("frame", 1, F.TYPE_MESSAGE, message="Frame"),
        Field("future_states", 5, F.TYPE_MESSAGE, message="EgoTrajectoryStates"),
        Field("past_states", 6, F.TYPE_MESSAGE, message="EgoTrajectoryStates"),
        Field("intent", 7, F.TYPE_INT32),
        Field("preference_trajectories", 8, F.TYPE_MESSAGE, repeated=True, message="EgoTrajectoryStates"),
    ],
}

_CLASSES = message_classes("lead_s2r/wod_e2e.proto", "lead_s2r.wod_e2e", _MESSAGES)
E2EDFrame = _CLASSES["E2EDFrame"]
EgoTrajectoryStates = _CLASSES["EgoTrajectoryStates"]
