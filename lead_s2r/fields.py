"""The one check that a value read from a JSON / YAML file has its field's type, for every reader of a file a user
hands us (configs, specs, results, scores).

Why one: the readers once wrote this six ways and disagreed (two let ``true`` pass as a number, and a YAML ``7``
drove as ``True``). The rules, the same everywhere: a bool is no number and a number no bool; an int stands for a
float, and a float must be finite; ``X | None`` admits null; ``Literal[...]`` admits its values; ``list[X]`` and
``tuple[X, ...]`` check every item; any other class is an ``isinstance`` test.
"""

import math
from collections.abc import Mapping, Sequence
from numbers import Integral, Real
from types import UnionType
from typing import Any, Literal, Union, get_args, get_origin

from lead_s2r.errors import UserError


def fits(value: Any, hint: Any) -> bool:
    """Whether ``value`` (as a JSON or YAML parser returns it) is of the type ``hint``."""
    origin = get_origin(hint)
    if origin is Literal:
        return any(value == option and type(value) is type(option) for option in get_args(hint))
    if origin in (Union, UnionType):
        return any(fits(value, member) for member in get_args(hint))
    if origin in (list, tuple):
        items = get_args(hint)
        return isinstance(value, list | tuple) and all(fits(item, items[0]) for item in value)
    if origin is dict:
        return isinstance(value, dict)
    if hint is None or hint is type(None):
        return value is None
    if hint is Any:
        return True
    if hint is float:
        return is_number(value)
    if hint is int:
        return isinstance(value, Integral) and not isinstance(value, bool)
    return isinstance(value, hint)


def is_number(value: Any, finite: bool = True) -> bool:
    """Whether ``value`` is a real number (numpy's too) and no bool; with ``finite``, neither NaN nor infinite."""
    return isinstance(value, Real) and not isinstance(value, bool) and (not finite or math.isfinite(value))


def describe(hint: Any) -> str:
    """A type hint in a user's words: ``int``, ``str or null``, ``one of 'route', 'waypoint'``, ``list of float``."""
    origin = get_origin(hint)
    if origin is Literal:
        return "one of " + ", ".join(repr(option) for option in get_args(hint))
    if origin in (Union, UnionType):
        return " or ".join(describe(member) for member in get_args(hint))
    if origin in (list, tuple):
        items = get_args(hint)
        return f"a list of {describe(items[0])}" if items else "a list"
    if hint is None or hint is type(None):
        return "null"
    return getattr(origin or hint, "__name__", str(hint))


def check_fields(
    mapping: Any,
    hints: Mapping[str, Any],
    where: str,
    error: type[Exception] = UserError,
    advice: str = "",
    at: str = "",
    required: Sequence[str] = (),
) -> dict[str, Any]:
    """``mapping`` when it is a mapping that holds the ``required`` fields and whose fields named in ``hints`` have
    their types; otherwise ``error`` with one line naming the file (``where``), the position in it (``at``, e.g.
    ``columns[0]``), the field, its value and what it should be, then ``advice``."""
    tail = f"; {advice}" if advice else ""
    if not isinstance(mapping, dict):
        raise error(f"{where}: {at or 'the file'} is {mapping!r}, not a mapping{tail}")
    missing = [name for name in required if name not in mapping]
    if missing:
        raise error(f"{where}: {f'{at}: ' if at else ''}missing field {missing[0]!r}{tail}")
    for name, hint in hints.items():
        if name in mapping and not fits(mapping[name], hint):
            field = f"{at}.{name}" if at else name
            raise error(f"{where}: {field} is {mapping[name]!r}, not {describe(hint)}{tail}")
    return mapping
