"""Write pickles that name nuPlan classes, as NAVSIM v2's synthetic scene pickles do, without nuPlan installed.

A real ``synthetic_scene_pickles/<token>.pkl`` holds nuPlan objects (``DetectionsTracks``, ``Agent``,
``TrafficLightStatuses``, ...). A reader must therefore cope with global references to ``nuplan.*`` classes. To
test such a reader the generator must write those references, and it must do so without a fake ``nuplan`` package
that could be imported. A stub module registered in ``sys.modules`` would let a careless reader "succeed" by
importing it. Instead, :class:`NuplanClass` is a plain value (a module path and a name), and the pickler writes it
as the same ``STACK_GLOBAL`` opcode a real class gets. :class:`NuplanObject` is written as such a class applied to
its arguments (``NEWOBJ``, or ``REDUCE`` for enums and classes with ``__reduce__``), followed by ``BUILD`` with its
attribute dict. This is the byte layout Python's pickler gives the real objects.

It uses the pure-Python pickler (``pickle._Pickler``): its per-type dispatch table is the documented way to write
custom opcodes. The C pickler offers no such hook for globals.
"""

import io
import pickle
from dataclasses import dataclass
from typing import Any, ClassVar


@dataclass(frozen=True, eq=False)
class NuplanClass:
    """A class by import path only. Keep one instance per class so the pickle memoises it like a real global."""

    module: str
    name: str


@dataclass(eq=False)
class NuplanObject:
    """An instance of a nuPlan class: constructor arguments and the attribute dict BUILD restores."""

    cls: NuplanClass
    args: tuple = ()
    state: dict[str, Any] | None = None
    reduce: bool = False  # REDUCE (call the class) instead of NEWOBJ (cls.__new__)


class _Pickler(pickle._Pickler):
    dispatch: ClassVar[dict] = dict(pickle._Pickler.dispatch)  # a copy: pickle's own table stays untouched

    def _save_class(self, obj: NuplanClass) -> None:
        self.save(obj.module)
        self.save(obj.name)
        self.write(pickle.STACK_GLOBAL)
        self.memoize(obj)

    def _save_object(self, obj: NuplanObject) -> None:
        self.save(obj.cls)
        self.save(tuple(obj.args))
        self.write(pickle.REDUCE if obj.reduce else pickle.NEWOBJ)
        self.memoize(obj)
        if obj.state is not None:
            self.save(obj.state)
            self.write(pickle.BUILD)

    dispatch[NuplanClass] = _save_class
    dispatch[NuplanObject] = _save_object


def dumps(obj: Any) -> bytes:
    """Pickle ``obj`` (protocol 4, as NAVSIM's ``HIGHEST_PROTOCOL`` of its Python), nuPlan stand-ins included."""
    buffer = io.BytesIO()
    _Pickler(buffer, protocol=4).dump(obj)
    return buffer.getvalue()
