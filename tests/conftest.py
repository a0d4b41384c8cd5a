"""Shared fixtures: tiny synthetic scenes generated once per test session."""

from __future__ import annotations

from pathlib import Path

import pytest

from ftgspp.config import DataConfig
from ftgspp.data.load import load_scene
from ftgspp.data.synthetic import generate

TINY = dict(width=64, height=48, n_frames=6, n_cameras=6)


@pytest.fixture(scope="session")
def tiny_scene_dir(tmp_path_factory) -> Path:
    """A 6-camera, 6-frame, 64x48 `studio` scene in the DyNeRF layout."""
    out = tmp_path_factory.mktemp("scenes") / "tiny_studio"
    return generate(out, layout="dynerf", preset="studio", seed=0, **TINY)


@pytest.fixture(scope="session")
def tiny_scene(tiny_scene_dir):
    return load_scene(DataConfig(path=str(tiny_scene_dir)))
