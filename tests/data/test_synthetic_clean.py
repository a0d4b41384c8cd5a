"""The held-out camera's noise-free frames (``gt/clean/``): what the recorded frames are without
their sensor noise, and the frames the diagnostics' flicker reference is measured on.

Oracles: with no noise the lossless video decodes to exactly the noise-free frames; with noise,
the generator's documented noise stream (``SeedSequence([seed, 2, camera])``, one normal draw per
frame in order) added to the noise-free frames gives the recorded ones up to the 8-bit rounding
of each; the loader's downsampled video and OpenCV's area resize of the noise-free frames agree.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from ftgspp.config import DataConfig
from ftgspp.data.load import load_scene
from ftgspp.data.synthetic.build import generate
from ftgspp.data.synthetic.content import build_scene, color_transforms, render_camera
from ftgspp.data.synthetic.presets import resolve_config
from ftgspp.diagnostics.motion import load_clean_frames

SMALL = dict(n_cameras=3, n_frames=4, width=64, height=48)


def test_without_noise_the_recorded_frames_are_the_noise_free_ones(tmp_path: Path) -> None:
    root = generate(tmp_path / "quiet", layout="dynerf", seed=1, noise=0.0, **SMALL)
    clean = np.load(root / "gt" / "clean" / "cam00.npy")
    assert clean.dtype == np.uint8 and clean.shape == (4, 48, 64, 3)
    assert sorted(p.name for p in (root / "gt" / "clean").iterdir()) == ["cam00.npy"]  # the test camera only
    scene = load_scene(DataConfig(path=str(root), downsample=1))
    assert scene.cameras[scene.test_ids[0]].name == "cam00"
    np.testing.assert_array_equal(scene.frames(scene.test_ids[0]), clean)  # FFV1 is lossless
    assert "clean" in json.loads((root / "gt" / "scene.json").read_text())["files"]


def test_the_recorded_frames_are_the_noise_free_ones_plus_the_noise(tmp_path: Path) -> None:
    root = generate(tmp_path / "noisy", layout="easyvolcap", seed=2, **SMALL)  # sensor noise 0.01
    clean = np.load(root / "gt" / "clean" / "cam00.npy").astype(np.float64) / 255.0
    recorded = np.stack([cv2.imread(str(p))[..., ::-1] for p in sorted((root / "images" / "cam00").glob("*.png"))])
    cfg = resolve_config("studio", 2, **SMALL)
    rng = np.random.default_rng(np.random.SeedSequence([2, 2, 0]))  # camera 0's noise stream
    noise = np.stack([rng.normal(0.0, cfg.noise, clean.shape[1:]) for _ in range(len(clean))])
    redone = np.round(np.clip(clean + noise, 0.0, 1.0) * 255)
    # the noise-free frames are rounded to 8 bits before the noise is added back: at most one level apart
    assert np.abs(redone - recorded).max() <= 1
    residual = recorded - clean * 255
    assert abs(residual.std() - 255 * cfg.noise) < 0.1 * 255 * cfg.noise  # without the noise: 2.55 levels apart


def test_keeping_the_noise_free_frames_leaves_the_recorded_ones_alone() -> None:
    cfg = resolve_config("studio", 0, n_cameras=2, n_frames=2, width=32, height=24, supersample=1)
    content, cams = build_scene(cfg)
    transform = color_transforms(cfg, 2)[0]
    plain = render_camera(content, cams[0], cfg, transform, 0)
    kept = render_camera(content, cams[0], cfg, transform, 0, keep_clean=True)
    assert plain.clean is None and kept.clean is not None
    np.testing.assert_array_equal(plain.frames, kept.frames)  # the same noise draws


@pytest.mark.parametrize("downsample", [1, 2])
def test_the_noise_free_frames_line_up_with_the_loaded_video(tmp_path: Path, downsample: int) -> None:
    root = generate(tmp_path / "s", layout="dynerf", seed=0, noise=0.0, **SMALL)
    scene = load_scene(DataConfig(path=str(root), downsample=downsample, frame_start=1, frame_end=3))
    cam = scene.test_ids[0]
    clean = load_clean_frames(scene, cam)
    full = np.load(root / "gt" / "clean" / "cam00.npy")[1:3]
    c = scene.cameras[cam]
    expected = np.stack([cv2.resize(f, (c.width, c.height), interpolation=cv2.INTER_AREA) for f in full])
    np.testing.assert_array_equal(clean, expected)
    np.testing.assert_array_equal(clean, scene.frames(cam))  # noise-free and lossless: what the run trains on
    assert load_clean_frames(scene, scene.train_ids[0]) is None  # training cameras have none
