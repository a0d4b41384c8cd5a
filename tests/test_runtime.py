"""The run environment (``ftgspp.runtime``): Numba's threading layer is chosen by an explicit call,
never by importing a module; ``enter`` applies a run's settings; the device resolver's errors."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from ftgspp.config import TrainConfig
from ftgspp.errors import InputError
from ftgspp.runtime import enter
from ftgspp.runtime.device import resolve_device

_LAYER_AFTER_IMPORTS = """
import numba
import ftgspp.render.cpu, ftgspp.render.prepare, ftgspp.ssim_cpu, ftgspp.trainer
from ftgspp.runtime.jit import configure_numba
print(numba.config.THREADING_LAYER, configure_numba(), configure_numba(), numba.config.THREADING_LAYER)
"""


def test_importing_the_kernels_leaves_the_threading_layer_to_configure_numba():
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_THREADING_LAYER"}
    r = subprocess.run([sys.executable, "-c", _LAYER_AFTER_IMPORTS], env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    after_imports, first, second, after = r.stdout.split()
    assert after_imports == "default", "an import chose the layer"
    assert first == second == after != "default"  # idempotent; omp where Numba can load it


def test_enter_applies_the_run_settings_in_this_process():
    before = torch.get_num_threads()
    try:
        env = enter(TrainConfig(device="cpu", threads=1))
        assert env.device == torch.device("cpu") and env.torch_threads == 1 == torch.get_num_threads()
        assert env.domain["mode"] == "default" and env.domain["torch_threads"] == "1" and env.domain["id"]
    finally:
        torch.set_num_threads(before)
    with pytest.raises(InputError, match="dispatch"):
        enter(TrainConfig(dispatch="sse9"))
    with pytest.raises(InputError, match="determinism"):
        enter(TrainConfig(determinism="exact"))


def test_device_resolution():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(InputError, match="device"):
        resolve_device("tpu9")
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="no CUDA device"):
            resolve_device("cuda")


_VECTOR_REGISTERS = """
import re
import ftgspp.runtime.jit  # noqa: F401  (chooses the features before the first kernel below)
from numba import njit

@njit(fastmath=False, error_model="numpy")
def fma_loop(a, b, c):
    for i in range(a.shape[0]):
        a[i] = a[i] * b[i] + c[i]

fma_loop.compile("void(float32[::1], float32[::1], float32[::1])")  # compiled, never run
asm = "".join(fma_loop.inspect_asm().values())
print(len(re.findall(r"%zmm\\d+", asm)), len(re.findall(r"%ymm\\d+", asm)))
"""


def _registers(**numba_env: str) -> tuple[int, int]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CPU")} | numba_env
    r = subprocess.run([sys.executable, "-c", _VECTOR_REGISTERS], env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    zmm, ymm = map(int, r.stdout.split())
    return zmm, ymm


def test_kernels_for_an_intel_avx512_cpu_use_512_bit_vectors():
    """LLVM's Intel tuning would compile the loop with 256-bit vectors (zmm 0, as the hand-chosen
    features show); importing the kernels' JIT options lifts it. Compiled only: any x86-64 host."""
    assert _registers(NUMBA_CPU_NAME="sapphirerapids", NUMBA_CPU_FEATURES="+prefer-256-bit")[0] == 0
    zmm, _ = _registers(NUMBA_CPU_NAME="sapphirerapids", NUMBA_CPU_FEATURES="")
    assert zmm > 0
    assert _registers(NUMBA_CPU_NAME="haswell", NUMBA_CPU_FEATURES="")[0] == 0  # AVX2: nothing to widen


def test_widened_features_leave_hand_chosen_features_and_avx2_alone():
    from ftgspp.runtime.jit import PREFER_256, vector_lanes, widened_features

    assert widened_features({"NUMBA_CPU_NAME": "skylake-avx512", "NUMBA_CPU_FEATURES": ""}) == PREFER_256
    assert widened_features({"NUMBA_CPU_NAME": "znver3", "NUMBA_CPU_FEATURES": ""}) is None
    assert widened_features({"NUMBA_CPU_NAME": "znver4", "NUMBA_CPU_FEATURES": "+avx512f"}) is None
    # the lanes follow the named CPU when the features only change its tuning
    assert vector_lanes({"NUMBA_CPU_NAME": "sapphirerapids", "NUMBA_CPU_FEATURES": PREFER_256}) == 16


_CALLER = """
from numba import njit
from ftgspp.runtime.jit import JIT
from callee import helper


@njit(**JIT)
def kernel(x):
    return helper(x)
"""
_RUN_CALLER = """
import sys
sys.path.insert(0, sys.argv[1])
import callee, caller
print(caller.kernel(1.0), type(caller.kernel._cache._impl.locator).__name__,
      type(callee.helper._cache._impl.locator).__name__)
"""


def test_a_cached_kernel_recompiles_when_a_function_it_calls_from_another_file_changes(tmp_path):
    """Numba stamps a cached kernel with its own file only: without ``jit.stamp_called_files`` a
    kernel calling ``helper`` from another file kept running the old ``helper`` from its cache."""
    (tmp_path / "caller.py").write_text(_CALLER)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}  # the cache in tmp_path/__pycache__

    def run(helper_body: str) -> list[str]:
        (tmp_path / "callee.py").write_text(
            f"from numba import njit\nfrom ftgspp.runtime.jit import JIT\n\n\n@njit(**JIT)\ndef helper(x):\n"
            f"    return {helper_body}\n")  # fmt: skip
        r = subprocess.run([sys.executable, "-c", _RUN_CALLER, str(tmp_path)], env=env, capture_output=True,
                           text=True)  # fmt: skip
        assert r.returncode == 0, r.stderr[-2000:]
        return r.stdout.split()

    assert run("x * 2.0") == ["2.0", "CalledFilesInTreeCacheLocator", "InTreeCacheLocator"]
    assert run("x * 2.0")[0] == "2.0"  # from the cache
    assert run("x * 3.0")[0] == "3.0"  # not the cached 2.0
    assert any((tmp_path / "__pycache__").glob("caller.kernel-*.nbi"))
