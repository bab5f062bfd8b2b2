"""Timing for the benchmarks: CPU time of this process per call (wall time on a shared machine says little), and
wall time where the work runs in other processes or is compared with a wall-clock figure."""

import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np

T = TypeVar("T")


def timed(function: Callable[[], T], clock: Callable[[], float] = time.perf_counter) -> tuple[T, float]:
    """``function()`` and the seconds it took by ``clock`` (wall time by default)."""
    start = clock()
    result = function()
    return result, clock() - start


def cpu_times_ms(function: Callable[[], object], repeats: int) -> np.ndarray:
    """CPU time in ms of ``repeats`` calls, after one warm-up call."""
    function()
    return 1e3 * np.asarray([timed(function, time.process_time)[1] for _ in range(repeats)])


def wall_times_ms(function: Callable[[], object], repeats: int, warm_up: bool = True) -> np.ndarray:
    """Wall time in ms of ``repeats`` calls, after one warm-up call unless ``warm_up`` is false."""
    if warm_up:
        function()
    return 1e3 * np.asarray([timed(function)[1] for _ in range(repeats)])
