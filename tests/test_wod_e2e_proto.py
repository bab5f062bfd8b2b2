"""Hand-written wire encoder (synthetic side) against our protobuf schema (adapter side); field-level errors."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lead_s2r.schema import Command, validate
from lead_s2r.synthetic.wod_e2e import encode_frame, frame_record, make_dataset
from lead_s2r.synthetic.wod_e2e_proto import States, e2ed_frame
from lead_s2r_adapters.wod_e2e import WodE2EAdapter, parse_frame
from lead_s2r_adapters.wod_e2e_proto import E2EDFrame, EgoTrajectoryStates

floats = st.lists(st.floats(width=32, allow_nan=False), max_size=25)


@settings(max_examples=60, deadline=None)
@given(x=floats, score=st.one_of(st.none(), st.floats(-1, 10, width=32)), seed=st.integers(0, 2**16))
def test_states_wire_round_trip(x, score, seed):
    y = np.random.default_rng(seed).normal(size=len(x)).astype(np.float32).tolist()
    parsed = EgoTrajectoryStates.FromString(States(x, y, vel_x=y, preference_score=score).encode())
    assert list(parsed.pos_x) == x and list(parsed.pos_y) == y and list(parsed.vel_x) == y
    assert not parsed.pos_z and not parsed.accel_y
    assert parsed.HasField("preference_score") is (score is not None)
    if score is not None:
        assert parsed.preference_score == score


@pytest.mark.parametrize("intent", [0, 1, 2, 3, 7, -1])
def test_intent_is_kept_raw_even_out_of_range(intent):
    frame = make_dataset(count=1).frames[0]
    frame.intent = intent
    message = parse_frame(encode_frame(frame))
    assert message.intent == intent and message.frame.context.name == frame.name
    assert len(message.frame.images) == 8 and message.frame.timestamp_micros == 0


def one_record_shard(tmp_path, payload: bytes):
    path = tmp_path / "training_0.tfrecord-00000-of-00001"
    path.write_bytes(frame_record(payload))
    adapter = WodE2EAdapter()
    (log,) = adapter.list_logs(tmp_path)
    return adapter, log, path


def test_unknown_intent_maps_to_unknown_command(tmp_path):
    frame = make_dataset(count=1).frames[0]
    frame.intent = 9
    adapter, log, _ = one_record_shard(tmp_path, encode_frame(frame))
    (sample,) = adapter.iter_samples(log)
    validate(sample)
    assert sample["meta"]["ego"]["command"] == Command.UNKNOWN and sample["meta"]["ego"]["command_raw"] == 9


def test_mismatched_state_columns_name_shard_offset_and_field(tmp_path):
    frame = make_dataset(count=1).frames[0]
    past = States([-1.0, 0.0], [0.0, 0.0], vel_x=[5.0], vel_y=[0.0, 0.0], accel_x=[0.0, 0.0], accel_y=[0.0, 0.0])
    payload = e2ed_frame(frame.name, [], [], past, None, 1)
    adapter, log, path = one_record_shard(tmp_path, payload)
    with pytest.raises(ValueError, match=rf"{path}: record at offset 0: past_states\.vel_x: 1 values, but pos_x has 2"):
        list(adapter.iter_samples(log))


def test_image_without_calibration_names_the_camera(tmp_path):
    frame = make_dataset(count=1).frames[0]
    message = parse_frame(encode_frame(frame))
    del message.frame.context.camera_calibrations[:]
    adapter, log, path = one_record_shard(tmp_path, message.SerializeToString())
    with pytest.raises(ValueError, match=rf"{path}: record at offset 0: frame.images\[name=\d\]: no frame.context"):
        list(adapter.iter_samples(log))


def test_unknown_fields_are_tolerated():
    frame = make_dataset(count=1).frames[0]
    payload = encode_frame(frame)
    extra = b"\x12\x03abc" + b"\x18\x05"  # fields 2 and 3: unused in the public E2EDFrame
    message = E2EDFrame.FromString(payload + extra)
    assert message.frame.context.name == frame.name and len(message.past_states.pos_x) == 16
