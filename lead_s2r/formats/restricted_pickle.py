"""Load source pickles (LEAD metas and boxes, OpenScene logs, NAVSIM v2 synthetic scenes) without letting them run code.

A pickle can name any importable callable. This unpickler admits only the builtin data types and what numpy needs
to rebuild arrays, dtypes and scalars (module layouts of numpy 1.x and 2.x). Anything else is refused by name.

Some sources pickle foreign classes: NAVSIM's synthetic scenes hold nuPlan objects. A caller may name such classes
(``records``). Each one is then rebuilt as a :class:`Record`, plain data holding the constructor arguments and the
attribute dict. Nothing is imported and none of the foreign code runs, so reading needs no nuPlan install.
"""

import _compat_pickle
import io
import pickle
import pickletools
from collections.abc import Collection
from functools import cache
from typing import IO, Any, ClassVar

import numpy as np

_BUILTINS = frozenset(
    {"dict", "list", "tuple", "set", "frozenset", "int", "float", "complex", "bool", "str", "bytes", "bytearray"}
    | {"slice", "range"}
)
#: The opcodes that store into the memo at an index they name.
_MEMO_PUTS = frozenset({"PUT", "BINPUT", "LONG_BINPUT"})
_NUMPY_RECONSTRUCTORS = frozenset({"_reconstruct", "scalar", "ndarray", "dtype", "_frombuffer"})
_NUMPY_MODULES = frozenset(
    {"numpy", "numpy.core.multiarray", "numpy._core.multiarray", "numpy.core.numeric", "numpy._core.numeric"}
)


class Record:
    """A foreign object rebuilt as plain data. ``path`` is its class's import path, ``args`` its constructor (or
    ``__new__``) arguments (an enum's value), and ``state`` the attribute dict its pickle restores."""

    path: ClassVar[str] = ""

    def __new__(cls, *args: Any) -> "Record":
        record = object.__new__(cls)
        record.args, record.state = args, {}
        return record

    def __init__(self, *args: Any) -> None:  # REDUCE calls the class; __new__ already kept the arguments
        pass

    def __setstate__(self, state: Any) -> None:
        if isinstance(state, tuple):  # (dict, slots) from classes with __slots__
            state = {**(state[0] or {}), **(state[1] or {})}
        self.state = dict(state)

    def __repr__(self) -> str:
        return f"Record({self.path}, args={self.args!r}, state={self.state!r})"


@cache
def record_class(module: str, name: str) -> type[Record]:
    """The :class:`Record` subclass standing in for ``module.name`` (one per path, so ``isinstance`` works)."""
    return type(name, (Record,), {"path": f"{module}.{name}"})


class RestrictedUnpickler(pickle.Unpickler):
    """Unpickles builtin containers and scalars and numpy arrays/scalars, and the classes named in ``records``
    (``(module, name)`` pairs) as :class:`Record`; raises UnpicklingError for the rest."""

    def __init__(self, file: IO[bytes], records: Collection[tuple[str, str]] = ()) -> None:
        super().__init__(file)
        self.records = frozenset(records)

    def find_class(self, module: str, name: str) -> Any:
        # protocol <= 2 pickles use Python 2 names (__builtin__.xrange...): translate them as pickle itself does
        if (module, name) in _compat_pickle.NAME_MAPPING:
            module, name = _compat_pickle.NAME_MAPPING[(module, name)]
        module = _compat_pickle.IMPORT_MAPPING.get(module, module)
        if (module, name) in self.records:
            return record_class(module, name)
        if _allowed(module, name):
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"pickle refers to {module}.{name}; only builtins and numpy are allowed")

    def persistent_load(self, pid: Any) -> Any:
        raise pickle.UnpicklingError("pickle uses persistent ids, which no supported source writes")


def _allowed(module: str, name: str) -> bool:
    if module == "builtins":
        return name in _BUILTINS
    if module == "_codecs":
        return name == "encode"  # how protocol-2 pickles store bytes
    if module == "numpy.dtypes":
        return name.endswith("DType")
    if module in _NUMPY_MODULES and name in _NUMPY_RECONSTRUCTORS:
        return True
    candidate = getattr(np, name, None) if module == "numpy" else None
    return isinstance(candidate, type) and issubclass(candidate, np.generic)


#: What unpickling a damaged (truncated, bit-flipped, retyped) pickle raises: the pickle machine's own errors, and
#: those of constructors (numpy's among them) called with arguments of the wrong type or value (numpy's dtype
#: ``__setstate__`` answers some with SystemError, "bad argument to internal function"). Readers catch these and name
#: the file; anything else is a bug.
DAMAGED = (
    pickle.UnpicklingError,
    EOFError,
    ValueError,
    TypeError,
    AttributeError,
    IndexError,
    KeyError,
    OverflowError,
    MemoryError,
    RecursionError,
    SystemError,
)


def load(file: IO[bytes], records: Collection[tuple[str, str]] = ()) -> Any:
    """Unpickle one object from a binary file with :class:`RestrictedUnpickler` (``records``: foreign classes to
    rebuild as :class:`Record`), once :func:`check_sizes` has passed its bytes."""
    data = file.read()
    check_sizes(data)
    return RestrictedUnpickler(io.BytesIO(data), records).load()


def check_sizes(data: bytes) -> None:
    """Raise UnpicklingError unless every size the pickle declares fits in it. The C unpickler allocates a counted
    bytes or bytearray, and grows its memo to a PUT's index, before it reads a byte of them: one flipped bit in a
    length or an index asked for gigabytes (a MemoryError, or the process killed when the memo's zeroed slots fit in
    memory). :mod:`pickletools` walks the opcodes reading what each declares, so a length past the end fails here;
    a memo index above the opcodes seen so far, or a frame longer than the rest, cannot come from a pickler."""
    try:
        for count, (opcode, argument, position) in enumerate(pickletools.genops(data)):
            if opcode.name in _MEMO_PUTS and argument > count:
                raise pickle.UnpicklingError(f"memo index {argument} at byte {position} after {count} opcodes")
            if opcode.name == "FRAME" and argument > len(data) - position:
                raise pickle.UnpicklingError(f"a frame of {argument} bytes at byte {position} of {len(data)}")
    except ValueError as err:  # pickletools' words for a length past the end, or an unknown opcode
        raise pickle.UnpicklingError(str(err)) from None
