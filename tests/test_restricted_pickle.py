import collections
import io
import os
import pickle

import numpy as np
import pytest

from lead_s2r.formats import restricted_pickle

VALUES = {
    "arrays": [np.arange(6, dtype=t).reshape(2, 3) for t in ("float16", "float32", "float64", "int8", "uint64")],
    "strings": np.array(["vehicle", "pedestrian"]),
    "scalars": [np.float32(1.5), np.int64(-3), np.bool_(True)],
    "builtins": {"t": (1, 2.0, "x", b"raw", None, True), "s": {1, 2}, "f": frozenset({3}), "c": 1j, "r": range(3)},
}


@pytest.mark.parametrize("protocol", [2, 4, 5])
def test_data_round_trips(protocol):
    loaded = restricted_pickle.load(io.BytesIO(pickle.dumps(VALUES, protocol=protocol)))
    for original, back in zip(VALUES["arrays"], loaded["arrays"], strict=True):
        assert back.dtype == original.dtype and np.array_equal(back, original)
    assert loaded["strings"].tolist() == ["vehicle", "pedestrian"]
    assert [type(v) for v in loaded["scalars"]] == [np.float32, np.int64, np.bool_]
    assert loaded["builtins"] == VALUES["builtins"]


class Payload:
    def __reduce__(self):
        return (os.system, ("echo owned",))


@pytest.mark.parametrize(
    ("value", "name"),
    [(Payload(), "system"), (collections.OrderedDict(a=1), "collections.OrderedDict"), (Payload, "Payload")],
)
def test_anything_else_is_refused_by_name(value, name):
    with pytest.raises(pickle.UnpicklingError, match=name):
        restricted_pickle.load(io.BytesIO(pickle.dumps(value)))


def test_a_declared_size_past_the_end_is_refused_before_anything_is_allocated():
    """One flipped bit in a counted length asked the C unpickler for that many bytes (2**60 here: a MemoryError; a
    few gigabytes: memory the fuzz of a NAVSIM log saw the process killed for)."""
    data = pickle.dumps(bytearray(b"abc"), protocol=5)
    at = data.index(b"\x96")  # BYTEARRAY8, then its 8-byte length
    damaged = data[: at + 1] + (2**60).to_bytes(8, "little") + data[at + 9 :]
    with pytest.raises(pickle.UnpicklingError, match="expected 1152921504606846976 bytes in a bytearray8"):
        restricted_pickle.load(io.BytesIO(damaged))


def test_a_memo_index_no_pickler_writes_is_refused():
    """The C unpickler grows (and zeroes) its memo to a PUT's index: 10**6 after one opcode is 16 MB here, a
    flipped high byte of a LONG_BINPUT tens of gigabytes."""
    damaged = b"\x80\x02]r" + (10**6).to_bytes(4, "little") + b"(K\x01K\x02e."
    assert pickle.loads(damaged) == [1, 2]  # what the unchecked unpickler made of it
    with pytest.raises(pickle.UnpicklingError, match="memo index 1000000 at byte 3 after 2 opcodes"):
        restricted_pickle.load(io.BytesIO(damaged))


def test_a_numpy_state_that_numpy_answers_with_system_error_counts_as_damage():
    """The fuzz of a NAVSIM log at seed 0: a flipped bit turned a dtype's state tuple into a dict."""
    data = pickle.dumps(np.dtype("<U12"), protocol=5)
    at = data.rindex(b"t")  # the TUPLE that closes the dtype's state
    with pytest.raises(restricted_pickle.DAMAGED) as raised:
        restricted_pickle.load(io.BytesIO(data[:at] + b"d" + data[at + 1 :]))
    assert raised.type is SystemError
