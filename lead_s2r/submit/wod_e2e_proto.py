"""Our own protobuf schema for WOD-E2E's ``end_to_end_driving_submission.proto``.

Built by :mod:`lead_s2r.formats.proto_schema`.

Field numbers as upstream (proto2; shared/research/wod_e2e.md §1.4). ``submission_type`` is Waymo's enum
``SubmissionType`` (UNKNOWN = 0, E2ED_SUBMISSION = 1), declared as int32: the same wire bytes. The message has no
probability field: exactly one trajectory per frame.
"""

from lead_s2r.formats.proto_schema import F, Field, message_classes

#: ``E2EDChallengeSubmission.SubmissionType.E2ED_SUBMISSION``.
E2ED_SUBMISSION = 1

_MESSAGES: dict[str, list[Field]] = {
    "TrajectoryPrediction": [
        Field("pos_x", 1, F.TYPE_FLOAT, repeated=True, packed=True),
        Field("pos_y", 2, F.TYPE_FLOAT, repeated=True, packed=True),
    ],
    "FrameTrajectoryPredictions": [
        Field("frame_name", 1, F.TYPE_STRING),
        Field("trajectory", 2, F.TYPE_MESSAGE, message="TrajectoryPrediction"),
    ],
    "E2EDChallengeSubmission": [
        Field("predictions", 1, F.TYPE_MESSAGE, repeated=True, message="FrameTrajectoryPredictions"),
        Field("submission_type", 2, F.TYPE_INT32),
        Field("account_name", 3, F.TYPE_STRING),
        Field("unique_method_name", 4, F.TYPE_STRING),
        Field("authors", 5, F.TYPE_STRING, repeated=True),
        Field("affiliation", 6, F.TYPE_STRING),
        Field("description", 7, F.TYPE_STRING),
        Field("method_link", 8, F.TYPE_STRING),
        Field("uses_public_model_pretraining", 11, F.TYPE_BOOL),
        Field("num_model_parameters", 12, F.TYPE_STRING),
        Field("public_model_names", 13, F.TYPE_STRING, repeated=True),
    ],
}

_CLASSES = message_classes("lead_s2r/wod_e2e_submission.proto", "lead_s2r.wod_e2e_submission", _MESSAGES)
E2EDChallengeSubmission = _CLASSES["E2EDChallengeSubmission"]
