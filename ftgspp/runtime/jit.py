"""How the project's Numba kernels are compiled and run: one set of options, one threading layer.

``JIT`` is the option set every kernel module compiles with (``@njit(**JIT)``); the
determinism guarantee relies on it: no fast-math (LLVM neither fuses multiply-adds, uses
approximate reciprocals nor reorders floating-point sums), NumPy's error model (division by
zero gives inf/nan instead of raising, as NumPy does), the GIL released, and the machine
code cached on disk (``NUMBA_CACHE_DIR``, else ``__pycache__`` next to the module).

``configure_numba()`` chooses the threading layer: OpenMP when Numba can load it and nobody
chose one (it starts a parallel region in a few microseconds; ``workqueue`` takes tens to
hundreds); ``NUMBA_THREADING_LAYER`` overrides the choice. Numba fixes the layer when the
first parallel kernel runs, so ``ftgspp.runtime.enter`` and the entry points of the ``cpu``
backend (``render.cpu.rasterize``, ``render.prepare.prepare``, ``ssim_cpu.ssim_same_cpu``)
call it first; importing a module never does. It is idempotent and cheap after the first call.

    from ftgspp.runtime.jit import JIT, configure_numba
    @njit(parallel=True, **JIT)
    def kernel(...): ...
"""

from __future__ import annotations

import importlib
import os

import numba

JIT = dict(cache=True, fastmath=False, error_model="numpy", nogil=True)

_configured: str | None = None  # the layer configure_numba requested, once it ran


def configure_numba() -> str:
    """Prefer Numba's OpenMP threading layer unless one was chosen; returns the requested layer."""
    global _configured
    if _configured is not None:
        return _configured
    if os.environ.get("NUMBA_THREADING_LAYER") or numba.config.THREADING_LAYER != "default":
        _configured = numba.config.THREADING_LAYER
        return _configured
    try:
        importlib.import_module("numba.np.ufunc.omppool")
    except ImportError:  # no OpenMP runtime: Numba's own search (tbb, omp, workqueue)
        _configured = numba.config.THREADING_LAYER
        return _configured
    numba.config.THREADING_LAYER = "omp"
    _configured = "omp"
    return _configured
