"""What a run's bits depend on (its determinism domain), and a portable mode that pins it.

On one machine the same config and seed repeat bit for bit. Across machines they need
not: torch picks vectorised kernels by CPU (``ATEN_CPU_CAPABILITY``), oneDNN and MKL
dispatch by ISA, NumPy and OpenCV have runtime-dispatched SIMD paths, glibc's libm picks
FMA variants, and reductions split by thread count. Training amplifies a last-bit
difference into ~0.01–0.1 dB.

Two modes (``TrainConfig.determinism``):

- ``default``: fastest; bits are those of this machine's *domain* (CPU model and ISA
  class, torch capability, oneDNN/MKL settings, thread counts, package versions).
- ``portable``: every ISA-dependent library path (torch, oneDNN, MKL, NumPy, OpenCV, glibc's
  libm) is pinned to the x86-64 baseline before any library starts
  (``portable_environment``), torch runs on a fixed number of threads, oneDNN is off,
  OpenCV on one thread. The same config then gives the same bits on any x86-64 machine with
  the same package versions, whatever its ISA or core count. The project's Numba kernels
  are not pinned to a target and compile for the host's ISA. Their bits do not depend on
  it: without fast-math LLVM neither fuses multiply-adds, uses approximate reciprocals nor
  reorders floating-point sums, so vectorised loops run each lane's IEEE operations
  unchanged; the libm functions they call (``exp``, ``log``) are pinned through glibc's
  hwcaps tunable; SVML stays off; and they reduce in a fixed order whatever the thread
  count. (Pinning them to the baseline, ``NUMBA_CPU_NAME=generic``, gave the same bits but
  a 7x slower rasterizer: without AVX, LLVM declines to vectorise its pixel loops.)
  ``tests/test_determinism.py`` checks this with kernels compiled for the baseline.

Environment variables are read when the libraries load, so the portable environment must
exist before Python imports torch: ``train()`` called in a process without it (``ftgspp
train determinism=portable`` included) trains in a child process that has it
(``ftgspp.runtime.child``).

    env = portable_environment(os.environ)      # for a subprocess
    domain = determinism_domain("portable")      # what to record with a run
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
from typing import Mapping

MODES = ("default", "portable")
MARKER = "FTGSPP_DETERMINISM"  # set to "portable" in a process started with the portable environment
PORTABLE_TORCH_THREADS = 1  # torch's own reductions split by thread count; Numba kernels do not

# Pinned to the x86-64 baseline (values read by the libraries at load time).
PORTABLE_FIXED = {
    "ATEN_CPU_CAPABILITY": "default",  # torch: no AVX2/AVX-512 kernels
    "ONEDNN_MAX_CPU_ISA": "SSE41",  # oneDNN (also switched off at run time)
    "MKL_CBWR": "COMPATIBLE",  # MKL: conditional numerical reproducibility, baseline code path
    "NUMBA_DISABLE_INTEL_SVML": "1",  # Numba: no ISA-specific vector math library
    "GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX512F,-AVX512VL,-AVX2,-FMA,-FMA4,-AVX",  # libm: no FMA variants
}


def _numpy_dispatched() -> list[str]:
    """NumPy's runtime-dispatched SIMD targets of this build (all disabled in portable mode).

    Every target, not only those this CPU has: NumPy reports a target the caller's
    environment already disabled as absent, and disabling an absent one is harmless."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__
    except ImportError:  # numpy 1.x
        from numpy.core._multiarray_umath import __cpu_dispatch__
    return list(__cpu_dispatch__)


def _opencv_dispatched() -> list[str]:
    """OpenCV's dispatched (starred) CPU features of this build, e.g. ``AVX2`` (disabled or not)."""
    import cv2

    return [f.strip("*?") for f in cv2.getCPUFeaturesLine().split() if f.startswith("*")]  # "?": disabled now


def portable_environment(base: Mapping[str, str]) -> dict[str, str]:
    """``base`` plus every variable portable mode needs; start a process with it."""
    env = dict(base)
    env.update(PORTABLE_FIXED)
    env["NPY_DISABLE_CPU_FEATURES"] = " ".join(_numpy_dispatched())
    env["OPENCV_CPU_DISABLE"] = ",".join(_opencv_dispatched())
    env[MARKER] = "portable"
    return env


def portable_env_active() -> bool:
    """Whether this process was started with the portable environment (and torch obeyed it)."""
    if os.environ.get(MARKER) != "portable":
        return False
    import torch

    return torch.backends.cpu.get_cpu_capability() == "DEFAULT"


def apply_runtime(mode: str, threads: int) -> int:
    """Settings made after import; returns the torch thread count the run uses.

    ``portable`` requires ``portable_env_active()`` (raises ``RuntimeError`` otherwise):
    torch on ``threads`` (or ``PORTABLE_TORCH_THREADS``) threads, oneDNN off, OpenCV on one
    thread. ``default`` sets torch's thread count when ``threads > 0``.
    """
    import torch

    if mode not in MODES:
        raise ValueError(f"unknown determinism mode '{mode}' (choose from {', '.join(MODES)})")
    if mode == "portable":
        if not portable_env_active():
            raise RuntimeError("determinism=portable needs its environment before torch starts: train it with "
                               "train() (it starts a child process that has it), or start Python with "
                               "ftgspp.runtime.determinism.portable_environment(os.environ)")
        import cv2

        torch.backends.mkldnn.enabled = False
        cv2.setNumThreads(1)
        threads = threads if threads > 0 else PORTABLE_TORCH_THREADS
    if threads > 0:
        torch.set_num_threads(threads)
    return torch.get_num_threads()


def effective_threads(mode: str, threads: int) -> int:
    """The torch thread count a run with these settings uses in this process."""
    if threads > 0:
        return threads
    if mode == "portable":
        return PORTABLE_TORCH_THREADS
    import torch

    return torch.get_num_threads()


def _cpu() -> tuple[str, set[str]]:
    """CPU model name and flags from /proc/cpuinfo (empty where it does not exist)."""
    try:
        text = open("/proc/cpuinfo").read()
    except OSError:
        return platform.processor() or platform.machine(), set()
    model, flags = "", set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "model name" and not model:
            model = value.strip()
        elif key.strip() == "flags" and not flags:
            flags = set(value.split())
    return model, flags


def isa_class(flags: set[str]) -> str:
    """x86-64 micro-architecture level from CPU flags: ``x86-64-v4`` (AVX-512), ``-v3`` (AVX2+FMA), ..."""
    if {"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl"} <= flags:
        return "x86-64-v4"
    if {"avx2", "fma", "bmi2", "movbe"} <= flags:
        return "x86-64-v3"
    if {"sse4_2", "popcnt", "ssse3"} <= flags:
        return "x86-64-v2"
    return "x86-64" if flags else platform.machine()


def determinism_domain(mode: str, threads: int = 0) -> dict[str, str]:
    """What this process's training bits depend on, plus ``id``: a short hash of the parts that
    decide the bits in ``mode`` (portable: versions and torch threads; default: also the CPU)."""
    import cv2
    import numba
    import numpy
    import torch

    model, flags = _cpu()
    info = {
        "mode": mode,
        "cpu_model": model,
        "isa_class": isa_class(flags),
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "onednn": "off" if not torch.backends.mkldnn.enabled else os.environ.get("ONEDNN_MAX_CPU_ISA", "max"),
        "mkl_cbwr": os.environ.get("MKL_CBWR", "auto"),
        "torch_threads": str(effective_threads(mode, threads)),
        "numba_threads": str(numba.config.NUMBA_NUM_THREADS),
        "versions": f"python {platform.python_version()}, torch {torch.__version__}, numpy {numpy.__version__}, "
                    f"numba {numba.__version__}, opencv {cv2.__version__}, glibc {platform.libc_ver()[1]}",
    }
    info["id"] = _domain_id(info)
    return info


# torch's name for the kernel set each ``TrainConfig.dispatch`` value selects
DISPATCH_CAPABILITY = {"avx512": "AVX512", "avx2": "AVX2", "baseline": "DEFAULT"}


def _domain_id(info: dict[str, str]) -> str:
    decisive = ["mode", "torch_threads", "versions"]
    if info["mode"] != "portable":
        decisive += ["cpu_model", "isa_class", "torch_cpu_capability", "onednn", "mkl_cbwr"]
    blob = json.dumps({k: info[k] for k in decisive}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:10]


def expected_domain_id(mode: str, threads: int = 0, dispatch: str = "native") -> str | None:
    """The domain id a run with these settings gets on this machine, computed without training;
    None when this process cannot tell (a default-mode run asked from a process that has the
    portable environment, whose own settings are not the machine's)."""
    info = determinism_domain(mode, threads)
    if mode == "portable":
        return info["id"]
    if os.environ.get(MARKER) == "portable":
        return None
    if dispatch != "native":
        info["torch_cpu_capability"] = DISPATCH_CAPABILITY[dispatch]
    return _domain_id(info)
