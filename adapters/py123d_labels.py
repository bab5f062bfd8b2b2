"""py123d box labels -> our :class:`BoxClass`.

A 123D log stores each box's label as the integer of a per-dataset enum and names that enum (by its qualified class
name) in the box file's metadata. Every such enum maps onto py123d's ``DefaultBoxDetectionLabel`` through its own
``to_default()``; we map those default names onto ours (:data:`DEFAULT_TO_BOXCLASS`). Where py123d is importable, any
dataset's enum is resolved through it; without py123d, the enums of the default labels and nuPlan (the ones 123D's
nuPlan, NAVSIM and CARLA/LEAD logs use) are known from the tables below (py123d 0.7's numbering). A label nothing
maps is kept as ``GENERIC_OBJECT`` with its raw ``Enum.NAME`` (or number) in ``meta.extras.py123d.box_labels``.
"""

import importlib
from functools import lru_cache

from lead_s2r.schema import BoxClass

#: py123d's DefaultBoxDetectionLabel names -> ours; EGO boxes are the ego itself and are dropped.
DEFAULT_TO_BOXCLASS: dict[str, BoxClass | None] = {
    "EGO": None,
    "VEHICLE": BoxClass.VEHICLE,
    "TRAIN": BoxClass.VEHICLE,
    "TWO_WHEELER": BoxClass.BICYCLE,
    "BICYCLE": BoxClass.BICYCLE,  # py123d 0.1's name, as LEAD's exporter wrote it
    "PERSON": BoxClass.PEDESTRIAN,
    "ANIMAL": BoxClass.GENERIC_OBJECT,
    "TRAFFIC_SIGN": BoxClass.CZONE_SIGN,
    "TRAFFIC_CONE": BoxClass.TRAFFIC_CONE,
    "TRAFFIC_LIGHT": BoxClass.TRAFFIC_LIGHT,
    "BARRIER": BoxClass.BARRIER,
    "GENERIC_OBJECT": BoxClass.GENERIC_OBJECT,
}

#: value -> default name of the enums known without py123d (py123d 0.7).
KNOWN_ENUMS: dict[str, dict[int, str]] = {
    "DefaultBoxDetectionLabel": {
        0: "EGO",
        1: "VEHICLE",
        2: "TRAIN",
        3: "TWO_WHEELER",
        4: "PERSON",
        5: "ANIMAL",
        6: "TRAFFIC_SIGN",
        7: "TRAFFIC_CONE",
        8: "TRAFFIC_LIGHT",
        9: "BARRIER",
        10: "GENERIC_OBJECT",
        11: "OTHER",
    },
    "NuPlanBoxDetectionLabel": {
        0: "VEHICLE",
        1: "TWO_WHEELER",
        2: "PERSON",
        3: "TRAFFIC_CONE",
        4: "BARRIER",
        5: "TRAFFIC_SIGN",
        6: "GENERIC_OBJECT",
    },
}


@lru_cache(maxsize=32)
def _enum(qualified: str) -> type | None:
    """The label enum named in a log, imported from py123d where it is installed."""
    module, _, name = qualified.rpartition(".")
    if not module:
        return None
    try:
        return getattr(importlib.import_module(module), name, None)
    except ImportError:
        return None


def default_name(qualified: str, value: int) -> str | None:
    """The DefaultBoxDetectionLabel name of label ``value`` of the enum ``qualified``; None where unknown."""
    short = qualified.rpartition(".")[2]
    if short in KNOWN_ENUMS:
        return KNOWN_ENUMS[short].get(value)
    enum = _enum(qualified)
    if enum is None:
        return None
    try:
        return enum(value).to_default().name
    except (ValueError, AttributeError, KeyError):
        return None


def box_class(qualified: str, value: int) -> tuple[BoxClass | None, str | None]:
    """(our class or None for the ego's own box, raw label where it mapped to nothing known)."""
    name = default_name(qualified, value)
    if name in DEFAULT_TO_BOXCLASS:
        return DEFAULT_TO_BOXCLASS[name], None
    raw = f"{qualified.rpartition('.')[2]}.{name}" if name is not None else f"{qualified.rpartition('.')[2]}#{value}"
    return BoxClass.GENERIC_OBJECT, raw
