"""Elementwise maths for the simulator's step functions, on numpy arrays or on Python floats alike.

A simulation step is ~80 tiny operations per proposal. numpy spends ~0.5 us on each whatever the array size,
Python float arithmetic ~50 ns, so the same step code (``lqr.track``, ``bicycle.propagate``) runs vectorised over
many proposals with ``NUMPY`` and per proposal on floats with ``FLOATS`` for a few (``simulation.py``). The step
code uses only arithmetic operators (shared by both) and these functions.
"""

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

#: what the step functions compute on: ``(N,)`` arrays, or one proposal's Python floats
Values = np.ndarray | float


class Elementwise(NamedTuple):
    sin: Callable[[Any], Any]
    cos: Callable[[Any], Any]
    tan: Callable[[Any], Any]
    arctan2: Callable[[Any, Any], Any]
    minimum: Callable[[Any, Any], Any]
    maximum: Callable[[Any, Any], Any]
    where: Callable[[Any, Any, Any], Any]


def _pick(condition: bool, if_true: float, if_false: float) -> float:
    return if_true if condition else if_false


NUMPY = Elementwise(np.sin, np.cos, np.tan, np.arctan2, np.minimum, np.maximum, np.where)
FLOATS = Elementwise(math.sin, math.cos, math.tan, math.atan2, min, max, _pick)
