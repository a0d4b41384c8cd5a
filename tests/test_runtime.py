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
