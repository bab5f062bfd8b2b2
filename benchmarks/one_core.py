"""Imported first by a benchmark timed on one core: BLAS and OpenMP threads pinned to 1 before numpy loads (and in
every process it starts, which inherits the environment)."""

import os

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_name] = "1"
