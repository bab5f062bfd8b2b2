"""Foreign-class pickles (nuPlan paths, numpy 1.x arrays) read back by the restricted unpickler and by pickle."""

import io
import pickle
import pickletools
import warnings

import numpy as np
import pytest

from lead_s2r.formats import restricted_pickle
from lead_s2r.formats.foreign_pickle import ForeignClass, ForeignObject, dumps, numpy1_array
from lead_s2r.formats.restricted_pickle import Record

SE2 = ForeignClass("nuplan.common.actor_state.state_representation", "StateSE2")
BOX = ForeignClass("nuplan.common.actor_state.oriented_box", "OrientedBox")
RECORDS = {(SE2.module, SE2.name), (BOX.module, BOX.name)}


def test_reduce_and_newobj_objects_come_back_as_records() -> None:
    centre = ForeignObject(SE2, (1.0, 2.0, 0.5), reduce=True)
    box = ForeignObject(BOX, (), {"_center": centre, "_length": 4.0})
    data = dumps({"boxes": [box, ForeignObject(BOX, (), {"_center": centre, "_length": 2.0})]})
    boxes = restricted_pickle.load(io.BytesIO(data), RECORDS)["boxes"]
    assert [b.path for b in boxes] == ["nuplan.common.actor_state.oriented_box.OrientedBox"] * 2
    assert type(boxes[0]) is type(boxes[1]) and isinstance(boxes[0], Record)
    assert boxes[0].state["_length"] == 4.0 and boxes[1].state["_length"] == 2.0
    assert boxes[0].state["_center"] is boxes[1].state["_center"]  # memoised once, as pickle shares objects
    assert boxes[0].state["_center"].args == (1.0, 2.0, 0.5)


def test_classes_not_named_are_refused_and_plain_pickle_needs_nuplan() -> None:
    data = dumps([ForeignObject(SE2, (0.0, 0.0, 0.0), reduce=True)])
    with pytest.raises(pickle.UnpicklingError, match="StateSE2"):
        restricted_pickle.load(io.BytesIO(data), {(BOX.module, BOX.name)})
    with pytest.raises(ModuleNotFoundError, match="nuplan"):
        pickle.loads(data)


def test_numpy1_array_layout_loads_here_and_names_no_numpy2_module() -> None:
    poses = (np.arange(24, dtype=np.float32).reshape(8, 3) - 5.5) / 4
    data = dumps({"poses": numpy1_array(poses)})
    modules = {arg for op, arg, _ in pickletools.genops(data) if op.name == "SHORT_BINUNICODE"}
    assert "numpy.core.multiarray" in modules and not any(m.startswith("numpy._core") for m in modules)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy 2 must load numpy 1's layout without a deprecation warning
        loaded = pickle.loads(data)["poses"]
    assert loaded.dtype == np.float32 and loaded.shape == (8, 3) and loaded.flags.writeable
    np.testing.assert_array_equal(loaded, poses)
    np.testing.assert_array_equal(restricted_pickle.load(io.BytesIO(data))["poses"], poses)
