"""Test helper: run a computation under each Numba thread count (1, 2 and 2 again)."""

from __future__ import annotations

from typing import Callable, TypeVar

import numba

from ftgspp.runtime.jit import configure_numba

T = TypeVar("T")


def under_thread_counts(fn: Callable[[], T]) -> list[T]:
    """``fn()`` with 1 thread, then 2 (twice, for run-to-run repeatability) where available."""
    configure_numba()  # as the kernels' entry points do, before Numba starts its threads
    threads = [1, 2] if numba.config.NUMBA_NUM_THREADS >= 2 else [1]
    before = numba.get_num_threads()
    results = []
    try:
        for n_threads in threads + [threads[-1]]:
            numba.set_num_threads(n_threads)
            results.append(fn())
    finally:
        numba.set_num_threads(before)
    return results
