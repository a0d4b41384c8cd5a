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


# LLVM CPU names whose default features include AVX-512 (``NUMBA_CPU_NAME`` without features)
AVX512_CPUS = frozenset((
    "x86-64-v4", "skylake-avx512", "cascadelake", "cooperlake", "cannonlake", "icelake-client", "icelake-server",
    "tigerlake", "rocketlake", "sapphirerapids", "emeraldrapids", "graniterapids", "knl", "knm", "znver4", "znver5",
))  # fmt: skip


def vector_lanes() -> int:
    """float32 lanes of the widest vectors the Numba kernels are compiled for: 16 with
    AVX-512, else 8 (AVX2; narrower ISAs split 8 lanes over several registers).

    The target is the one Numba compiles for: ``NUMBA_CPU_FEATURES`` when set, else the named
    CPU (``NUMBA_CPU_NAME``, ``AVX512_CPUS``), else the host. Kernels size their vectorised
    loops with it; their results do not depend on it, only their speed."""
    features = os.environ.get("NUMBA_CPU_FEATURES")
    if features:
        return 16 if "+avx512f" in features.split(",") else 8
    name = os.environ.get("NUMBA_CPU_NAME", "host")
    if name not in ("", "host"):
        return 16 if name in AVX512_CPUS else 8
    import llvmlite.binding as ll

    return 16 if ll.get_host_cpu_features().get("avx512f") else 8


_short_loops = False


def allow_short_vector_loops() -> None:
    """Let LLVM vectorise loops of 8 known iterations that need a runtime overlap check.

    LLVM's loop vectoriser treats a loop with fewer than 16 known iterations as "tiny" and
    vectorises it only if that costs no runtime check; the backward raster pass's 8-column
    loops (``RB`` on AVX2) read the tile state and write the per-column sums, two arrays whose
    overlap LLVM checks at run time, so by default they stay scalar (backward 8.2 instead of
    3.4 ms on the bench scene, `ftgspp bench render --target haswell`). Lowering
    ``-vectorizer-min-trip-count`` to 8 changes which loops are vectorised, never their results
    (no fast-math: no reordering). Applies to kernels compiled later in this process; once per
    process (LLVM rejects an option given twice)."""
    global _short_loops
    if not _short_loops:
        import llvmlite.binding as ll

        ll.set_option("ftgspp", "-vectorizer-min-trip-count=8")
        _short_loops = True
