"""Elementwise maths for the simulator's step functions, on numpy arrays or on Python floats alike.

A simulation step is ~80 tiny operations per proposal. numpy spends ~0.5 us on each whatever the array size,
Python float arithmetic ~50 ns, so the same step code (``lqr.track``, ``bicycle.propagate``) runs vectorised over
many proposals with ``NUMPY`` and per proposal on floats with ``FLOATS`` for a few (``simulation.py``). The step
code uses only arithmetic operators (shared by both) and these functions.

Every row's result is independent of the other rows, so one proposal scored alone gets the bits it gets among
thousands (``score_vocabulary``): ``FLOATS`` takes tan and arctan2 from numpy (``math``'s differ from numpy's SIMD
loops in the last bit; sin and cos agree), and :func:`row_products` multiplies each row by a matrix on its own,
where one BLAS product over all rows rounds a row differently depending on how many rows come with it.
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


def _numpy_tan(angle: float) -> float:
    return float(np.tan(angle))


def _numpy_arctan2(y: float, x: float) -> float:
    return float(np.arctan2(y, x))


def row_products(values: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """``values (..., K) @ matrix (K, M)`` with every row ``values[..., :]`` multiplied on its own (a stack of
    ``(1, K) @ (K, M)`` products), so its result does not depend on the rows beside it."""
    return (np.asarray(values)[..., None, :] @ matrix)[..., 0, :]


def _pick(condition: bool, if_true: float, if_false: float) -> float:
    return if_true if condition else if_false


NUMPY = Elementwise(np.sin, np.cos, np.tan, np.arctan2, np.minimum, np.maximum, np.where)
FLOATS = Elementwise(math.sin, math.cos, _numpy_tan, _numpy_arctan2, min, max, _pick)
