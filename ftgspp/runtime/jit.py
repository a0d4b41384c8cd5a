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
backend (``render.cpu.rasterize``, ``render.prepare.fused_prepare``, ``ssim_cpu.ssim_same_cpu``)
call it first; importing a module never does. It is idempotent and cheap after the first call.

Importing this module does two things, both before the first kernel is defined:
``widen_vectors()`` (on an AVX-512 target it lifts LLVM's preference for 256-bit vectors, Intel's
tuning; the kernels' rows are sized by ``vector_lanes()``), and ``stamp_called_files()``: Numba
decides whether a kernel's cached machine code is current from the kernel's own source file
only, so a kernel that calls a Numba function of another file (a method's fused kernel calls
the shared block functions of ``render/prepare_kernels.py``) would keep running the old code of
that function after it changed; its cache stamp covers those files too.

    from ftgspp.runtime.jit import JIT, configure_numba
    @njit(parallel=True, **JIT)
    def kernel(...): ...
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import inspect
import os
from collections.abc import Mapping

import numba
from numba.core import config as numba_config

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


def vector_lanes(environ: Mapping[str, str] = os.environ) -> int:
    """float32 lanes of the widest vectors the Numba kernels are compiled for: 16 with
    AVX-512, else 8 (AVX2; narrower ISAs split 8 lanes over several registers).

    As Numba decides: without ``NUMBA_CPU_FEATURES`` the host's features, whatever
    ``NUMBA_CPU_NAME`` says; with it, ``avx512f`` when the string names it (``+`` or ``-``),
    else the named CPU's defaults (``AVX512_CPUS``), else the host's. Kernels size their
    vectorised loops with it; their results do not depend on it, only their speed."""
    features = environ.get("NUMBA_CPU_FEATURES")
    if features is not None:
        flags = features.split(",")
        if "+avx512f" in flags or "-avx512f" in flags:
            return 16 if "+avx512f" in flags else 8
        name = environ.get("NUMBA_CPU_NAME") or "host"
        if name != "host":
            return 16 if name in AVX512_CPUS else 8
    import llvmlite.binding as ll

    return 16 if ll.get_host_cpu_features().get("avx512f") else 8


PREFER_256 = "-prefer-256-bit"  # LLVM tuning feature, removed: 512-bit vectors on AVX-512 targets


def widened_features(environ: Mapping[str, str] = os.environ) -> str | None:
    """The Numba CPU features that let LLVM use 512-bit vectors on an AVX-512 target, or None
    to leave Numba's choice (no AVX-512, or ``NUMBA_CPU_FEATURES`` chosen by hand).

    LLVM's tuning for Intel's AVX-512 CPUs (``skylake-avx512`` to ``emeraldrapids``) prefers
    256-bit vectors, against the clock drops of early AVX-512 parts; for AMD's (``znver4``) it
    does not. The raster kernels' 16-column rows are one 512-bit vector; compiled with 256-bit
    ones they lose the speed of both widths (``ftgspp bench render --asm`` counts the
    registers). The answer is the features Numba would use with that tuning removed: the
    host's (Numba's choice unless ``NUMBA_CPU_FEATURES`` is set, whatever ``NUMBA_CPU_NAME``
    says) or, when it is set empty, the named CPU's defaults; plus ``-prefer-256-bit``."""
    features = environ.get("NUMBA_CPU_FEATURES")
    if features or vector_lanes(environ) != 16:
        return None
    if features == "" and (environ.get("NUMBA_CPU_NAME") or "host") != "host":
        return PREFER_256  # the named CPU's defaults, minus the tuning
    from numba.core.codegen import get_host_cpu_features  # the host's features as Numba reads them

    return f"{get_host_cpu_features()},{PREFER_256}"


def widen_vectors() -> bool:
    """Apply ``widened_features()`` to this process's Numba; True when it changed anything.

    It changes the machine code, never the results (no fast-math: lanes never reorder the
    arithmetic). It must run before Numba builds its code generator, which its first ``@njit``
    definition does: this module calls it when imported, and every kernel module imports it
    before defining a kernel. It sets Numba's config, not the environment, so a child process
    (or another target of ``ftgspp bench --target``) decides for itself."""
    features = widened_features()
    if features is None:
        return False
    numba_config.CPU_FEATURES = features
    return True


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


def called_files(py_func) -> tuple[str, ...]:
    """The source files, other than its own, of the Numba functions a kernel's module has in its
    globals (the functions it may call), and of theirs in turn; sorted."""
    from numba.core.dispatcher import Dispatcher

    own = inspect.getfile(py_func)
    seen: set[str] = set()
    todo = [py_func.__globals__]
    while todo:
        for value in todo.pop().values():
            if isinstance(value, Dispatcher) and (path := inspect.getfile(value.py_func)) not in seen | {own}:
                seen.add(path)
                todo.append(value.py_func.__globals__)
    return tuple(sorted(seen))


@functools.lru_cache(maxsize=None)
def _file_digest(path: str, mtime: float, size: int) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


class _CalledFilesStamp:
    """A Numba cache locator's stamp that covers the files of the functions a kernel calls from other
    files as well as its own (mixed into Numba's locators by ``stamp_called_files``)."""

    _called: tuple[str, ...] = ()

    @classmethod
    def from_function(cls, py_func, py_file):
        called = called_files(py_func)
        if not called:  # Numba's own locator then, with its own stamp
            return None
        locator = super().from_function(py_func, py_file)
        if locator is not None:
            locator._called = called
        return locator

    def get_source_stamp(self):
        digests = tuple(_file_digest(f, os.stat(f).st_mtime, os.stat(f).st_size) for f in self._called)
        return super().get_source_stamp(), digests


def stamp_called_files() -> None:
    """Put ``_CalledFilesStamp`` locators first in Numba's list (where ``NUMBA_CACHE_DIR`` or the
    module's ``__pycache__`` holds the cache, as Numba's first two); once per process. Kernels that
    call no other file's Numba function keep Numba's own locators and stamps."""
    from numba.core import caching

    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl  # _CacheImpl in older Numba
    classes = impl._locator_classes
    if any(issubclass(c, _CalledFilesStamp) for c in classes):
        return
    ours = [type(f"CalledFiles{c.__name__}", (_CalledFilesStamp, c), {})
            for c in (caching.UserProvidedCacheLocator, caching.InTreeCacheLocator)]  # fmt: skip
    classes[:0] = ours


widen_vectors()  # before any kernel module defines its first kernel (see the docstring)
stamp_called_files()
