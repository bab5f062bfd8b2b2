"""nuPlan-path pickles (synthetic writer) read back by the restricted unpickler as plain records."""

import io
import pickle

import pytest

from lead_s2r import restricted_pickle
from lead_s2r.restricted_pickle import Record
from lead_s2r.synthetic.nuplan_pickle import NuplanClass, NuplanObject, dumps

SE2 = NuplanClass("nuplan.common.actor_state.state_representation", "StateSE2")
BOX = NuplanClass("nuplan.common.actor_state.oriented_box", "OrientedBox")
RECORDS = {(SE2.module, SE2.name), (BOX.module, BOX.name)}


def test_reduce_and_newobj_objects_come_back_as_records() -> None:
    centre = NuplanObject(SE2, (1.0, 2.0, 0.5), reduce=True)
    box = NuplanObject(BOX, (), {"_center": centre, "_length": 4.0})
    data = dumps({"boxes": [box, NuplanObject(BOX, (), {"_center": centre, "_length": 2.0})]})
    boxes = restricted_pickle.load(io.BytesIO(data), RECORDS)["boxes"]
    assert [b.path for b in boxes] == ["nuplan.common.actor_state.oriented_box.OrientedBox"] * 2
    assert type(boxes[0]) is type(boxes[1]) and isinstance(boxes[0], Record)
    assert boxes[0].state["_length"] == 4.0 and boxes[1].state["_length"] == 2.0
    assert boxes[0].state["_center"] is boxes[1].state["_center"]  # memoised once, as pickle shares objects
    assert boxes[0].state["_center"].args == (1.0, 2.0, 0.5)


def test_classes_not_named_are_refused_and_plain_pickle_needs_nuplan() -> None:
    data = dumps([NuplanObject(SE2, (0.0, 0.0, 0.0), reduce=True)])
    with pytest.raises(pickle.UnpicklingError, match="StateSE2"):
        restricted_pickle.load(io.BytesIO(data), {(BOX.module, BOX.name)})
    with pytest.raises(ModuleNotFoundError, match="nuplan"):
        pickle.loads(data)
