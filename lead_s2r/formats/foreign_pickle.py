"""Write pickles that name classes of packages we do not install (nuPlan, NAVSIM), as their owners' files do.

Two needs meet here. NAVSIM v2's synthetic scene pickles hold nuPlan objects, so the synthetic generator must
write ``nuplan.*`` global references to test our reader. A NAVSIM leaderboard submission must hold NAVSIM's
``Trajectory`` and nuPlan's ``TrajectorySampling``, because the server unpickles it with both installed. Neither
may rely on a fake package: a stub module registered in ``sys.modules`` (or left on ``sys.path``) would let a
careless reader "succeed" by importing it, and would hide a wrong module path until the server rejects the file.
Instead, :class:`ForeignClass` is a plain value (a module path and a name), and the pickler writes it as the same
``STACK_GLOBAL`` opcode a real class gets. :class:`ForeignObject` is written as such a class applied to its
arguments (``NEWOBJ``, or ``REDUCE`` for enums, functions and classes with ``__reduce__``), followed by ``BUILD``
with its state. This is the byte layout Python's pickler gives the real objects (a dataclass: ``NEWOBJ`` with no
arguments, then ``BUILD`` with its ``__dict__``; ``__post_init__`` does not run on load).

Arrays: numpy 2 pickles an array as ``numpy._core.multiarray._reconstruct``, a module numpy < 1.26 does not have;
NAVSIM pins numpy 1.23.4, so such a file fails on its server. :func:`numpy1_array` writes numpy 1.x's layout
(``numpy.core.multiarray._reconstruct``), which every numpy since 1.x still loads.

It uses the pure-Python pickler (``pickle._Pickler``), whose per-type dispatch table is the documented way to write
custom opcodes; the C pickler has no such hook for globals."""

import io
import pickle
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

#: Protocol of NAVSIM's ``pickle.dump`` on its Python (3.9: ``DEFAULT_PROTOCOL`` 4); readable since Python 3.4.
PROTOCOL = 4


@dataclass(frozen=True, eq=False)
class ForeignClass:
    """A class (or function) by import path only. Keep one instance per class so the pickle memoises it like a
    real global."""

    module: str
    name: str

    @property
    def path(self) -> str:
        return f"{self.module}.{self.name}"


@dataclass(eq=False)
class ForeignObject:
    """An instance of a foreign class: constructor arguments and the state BUILD restores (a dict, or the tuple a
    class's ``__setstate__`` takes)."""

    cls: ForeignClass
    args: tuple = ()
    state: Any = None
    reduce: bool = False  # REDUCE (call the class) instead of NEWOBJ (cls.__new__)


_RECONSTRUCT = ForeignClass("numpy.core.multiarray", "_reconstruct")
_NDARRAY = ForeignClass("numpy", "ndarray")
_DTYPE = ForeignClass("numpy", "dtype")


def numpy1_array(array: np.ndarray) -> ForeignObject:
    """``array`` as numpy 1.x pickles it: ``_reconstruct(ndarray, (0,), b'b')``, then ``__setstate__`` with
    (version 1, shape, dtype, Fortran order False, C-order bytes). Fixed-size numeric dtypes only."""
    array = np.ascontiguousarray(array)
    if array.dtype.hasobject or array.dtype.fields is not None:
        raise TypeError(f"numpy1_array: plain numeric dtypes only, got {array.dtype}")
    order = "|" if array.dtype.byteorder == "|" else "<" if array.dtype.byteorder in "<=" else ">"
    code = array.dtype.kind + str(array.dtype.itemsize)
    dtype = ForeignObject(_DTYPE, (code, False, True), (3, order, None, None, None, -1, -1, 0), reduce=True)
    state = (1, tuple(array.shape), dtype, False, array.tobytes())
    return ForeignObject(_RECONSTRUCT, (_NDARRAY, (0,), b"b"), state, reduce=True)


class _Pickler(pickle._Pickler):
    dispatch: ClassVar[dict] = dict(pickle._Pickler.dispatch)  # a copy: pickle's own table stays untouched

    def _save_class(self, obj: ForeignClass) -> None:
        self.save(obj.module)
        self.save(obj.name)
        self.write(pickle.STACK_GLOBAL)
        self.memoize(obj)

    def _save_object(self, obj: ForeignObject) -> None:
        self.save(obj.cls)
        self.save(tuple(obj.args))
        self.write(pickle.REDUCE if obj.reduce else pickle.NEWOBJ)
        self.memoize(obj)
        if obj.state is not None:
            self.save(obj.state)
            self.write(pickle.BUILD)

    dispatch[ForeignClass] = _save_class
    dispatch[ForeignObject] = _save_object


def dumps(obj: Any) -> bytes:
    """Pickle ``obj`` (protocol :data:`PROTOCOL`), foreign classes and objects included."""
    buffer = io.BytesIO()
    _Pickler(buffer, protocol=PROTOCOL).dump(obj)
    return buffer.getvalue()
