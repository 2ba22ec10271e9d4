"""numba, configured once for every compiled module of diffsurf (kernel.py, fastcsv.py).

Parallel loops run on OpenMP, else numba's own work queue, and TBB last: probing an old libtbb
prints warnings on stderr, which a command-line tool must not. A user's own choice
(NUMBA_THREADING_LAYER or NUMBA_THREADING_LAYER_PRIORITY) is left alone.
"""
from __future__ import annotations

import os

import numba

if "NUMBA_THREADING_LAYER" not in os.environ and "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ:
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]

__all__ = ["numba"]
