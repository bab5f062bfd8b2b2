"""CPU time of this process per call, for the scoring benchmarks (wall time on a shared machine says little)."""

import time
from collections.abc import Callable

import numpy as np


def cpu_times_ms(function: Callable[[], object], repeats: int) -> np.ndarray:
    """CPU time in ms of ``repeats`` calls, after one warm-up call."""
    function()
    times = []
    for _ in range(repeats):
        started = time.process_time()
        function()
        times.append(time.process_time() - started)
    return 1e3 * np.asarray(times)
