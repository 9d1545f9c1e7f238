"""Running many independent linear-algebra jobs of an analysis (eigendecompositions, ridge fits) at once on the CPU."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from threadpoolctl import threadpool_limits


def map_in_threads(function: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
    """`[function(item) for item in items]`, one thread per core, each job on one BLAS thread. Why: the jobs are
    NumPy/LAPACK calls that release the GIL, and at an analysis's sizes (matrices of hundreds of units) a BLAS call
    hardly speeds up with threads (a 512 x 512 `eigvals` took 1.1 s with 2 OpenBLAS threads, 0.33 s with 1, on 2
    cores), while independent jobs in parallel scale with the cores."""
    with threadpool_limits(1), ThreadPoolExecutor(os.cpu_count()) as pool:
        return list(pool.map(function, items))
