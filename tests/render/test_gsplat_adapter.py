"""The gsplat adapter without gsplat: where its requirements are checked, and that nothing
imports gsplat before it is used. Its numbers are checked through gsplat's own code in
``test_gsplat_parity.py``.
"""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from ftgspp.render import gsplat_adapter, resolve_backend


def test_gsplat_is_checked_at_backend_resolution() -> None:
    with pytest.raises(RuntimeError, match="'gsplat' needs CUDA tensors"):
        resolve_backend("gsplat", torch.device("cpu"))
    if "gsplat" not in sys.modules and not _installed():
        with pytest.raises(RuntimeError, match="'gsplat' is unavailable"):
            resolve_backend("gsplat", torch.device("cuda"))


def _installed() -> bool:
    import importlib.util

    return importlib.util.find_spec("gsplat") is not None


def test_importing_the_renderer_does_not_import_gsplat() -> None:
    code = "import sys, ftgspp.render, ftgspp.render.gsplat_adapter, ftgspp.bench; print('gsplat' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_a_missing_gsplat_is_a_runtime_error_naming_the_backend(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "gsplat", None)  # as if it were not installed
    with pytest.raises(RuntimeError, match="'gsplat' is unavailable"):
        gsplat_adapter.rasterize(torch.zeros(1, 2), torch.ones(1, 3), torch.ones(1, 3), torch.ones(1),
                                 torch.ones(1), torch.ones(1, 2), 8, 8)  # fmt: skip
