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
