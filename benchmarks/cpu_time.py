"""Timing for the benchmarks: CPU time of this process per call (wall time on a shared machine says little), and
wall time where the work runs in other processes or is compared with a wall-clock figure."""

import contextlib
import time
from collections.abc import Callable, Iterator
from typing import TypeVar

import numpy as np

T = TypeVar("T")


def timed(function: Callable[[], T], clock: Callable[[], float] = time.perf_counter) -> tuple[T, float]:
    """``function()`` and the seconds it took by ``clock`` (wall time by default)."""
    start = clock()
    result = function()
    return result, clock() - start


def wall_and_cpu(function: Callable[[], T]) -> tuple[T, float, float]:
    """``function()``, the wall seconds it took and the CPU seconds of this process it took."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = function()
    return result, time.perf_counter() - wall, time.process_time() - cpu


def cpu_times_ms(function: Callable[[], object], repeats: int) -> np.ndarray:
    """CPU time in ms of ``repeats`` calls, after one warm-up call."""
    function()
    return 1e3 * np.asarray([timed(function, time.process_time)[1] for _ in range(repeats)])


def wall_times_ms(function: Callable[[], object], repeats: int, warm_up: bool = True) -> np.ndarray:
    """Wall time in ms of ``repeats`` calls, after one warm-up call unless ``warm_up`` is false."""
    if warm_up:
        function()
    return 1e3 * np.asarray([timed(function)[1] for _ in range(repeats)])


@contextlib.contextmanager
def local_ray(cpus: int) -> Iterator[None]:
    """Ray started on this machine with ``cpus`` CPUs for the block, shut down after."""
    import ray

    ray.init(address="local", num_cpus=cpus, include_dashboard=False, log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()
