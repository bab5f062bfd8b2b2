"""Load source pickles (LEAD metas and boxes, OpenScene logs) without letting them run code.

A pickle can name any importable callable; this unpickler admits only the builtin data types and what numpy needs
to rebuild arrays, dtypes and scalars (module layouts of numpy 1.x and 2.x). Anything else is refused by name.
"""

import _compat_pickle
import pickle
from typing import IO, Any

import numpy as np

_BUILTINS = frozenset(
    {"dict", "list", "tuple", "set", "frozenset", "int", "float", "complex", "bool", "str", "bytes", "bytearray"}
    | {"slice", "range"}
)
_NUMPY_RECONSTRUCTORS = frozenset({"_reconstruct", "scalar", "ndarray", "dtype", "_frombuffer"})
_NUMPY_MODULES = frozenset(
    {"numpy", "numpy.core.multiarray", "numpy._core.multiarray", "numpy.core.numeric", "numpy._core.numeric"}
)


class RestrictedUnpickler(pickle.Unpickler):
    """Unpickles builtin containers and scalars and numpy arrays/scalars; raises UnpicklingError for the rest."""

    def find_class(self, module: str, name: str) -> Any:
        # protocol <= 2 pickles use Python 2 names (__builtin__.xrange...): translate them as pickle itself does
        if (module, name) in _compat_pickle.NAME_MAPPING:
            module, name = _compat_pickle.NAME_MAPPING[(module, name)]
        module = _compat_pickle.IMPORT_MAPPING.get(module, module)
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


def load(file: IO[bytes]) -> Any:
    """Unpickle one object from a binary file with :class:`RestrictedUnpickler`."""
    return RestrictedUnpickler(file).load()
