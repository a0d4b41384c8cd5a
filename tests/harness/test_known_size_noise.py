"""The known-size scene with a noise floor: sensor noise of SD σ (8-bit units) and 8-bit rounding.

Oracles: the noise a pixel gets is checked against the distribution it is drawn from (the
expected squared error of a rounded, clipped normal, summed over the 256 levels with scipy's
normal CDF), and the written videos, decoded by the scene loader, against the noise-free scene
of the same seed: away from the clipped ends their PSNR is the formula 20·log10(255/σ), less the
two roundings' 1/12 each.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from ftgspp.config import DataConfig
from ftgspp.data.load import load_scene
from ftgspp.errors import InputError
from harness.run import known_size
from harness.spec.known_scene import resolve

TINY = dict(k=60, n_cameras=4, n_frames=4, width=64, height=48, sigma_px=2.0)
SD = 2.0


def expected_mse(level: np.ndarray, sd: float) -> np.ndarray:
    """E[(clip(round(level + N(0, sd²)), 0, 255) − level)²] per element, from the normal CDF."""
    k = np.arange(256.0)
    lo = np.where(k == 0, -np.inf, k - 0.5)
    hi = np.where(k == 255, np.inf, k + 0.5)
    z = level[..., None]
    p = stats.norm.cdf((hi - z) / sd) - stats.norm.cdf((lo - z) / sd)  # [..., 256]: P(the read-out is k)
    return (p * (k - level[..., None]) ** 2).sum(axis=-1)


def test_the_noise_is_the_stated_distribution() -> None:
    rng = np.random.default_rng(0)
    level = np.concatenate([rng.uniform(20, 235, 200_000), np.zeros(100_000), np.full(50_000, 254.6)])
    noisy = known_size.add_noise(level, SD, np.random.default_rng(1))
    assert noisy.dtype == np.uint8
    measured = ((noisy - level) ** 2)
    for part in (slice(0, 200_000), slice(200_000, 300_000), slice(300_000, None)):
        assert measured[part].mean() == pytest.approx(expected_mse(level[part][:2000], SD).mean(), rel=0.02)
    mid = measured[:200_000].mean()  # no clipping: σ² + 1/12, the formula's ceiling
    assert 10 * math.log10(255**2 / mid) == pytest.approx(20 * math.log10(255 / SD), abs=0.15)
    again = known_size.add_noise(level, SD, np.random.default_rng(1))
    assert np.array_equal(again, noisy)  # seeded


@pytest.fixture(scope="module")
def scenes(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("noise")
    clean = known_size.generate(root / "clean", seed=4, **TINY)
    noisy = known_size.generate(root / "noisy", seed=4, noise_sd=SD, **TINY)
    return clean, noisy


def test_the_noisy_frames_psnr_against_the_noise_free_ones_is_the_formula(scenes: tuple[Path, Path]) -> None:
    clean_dir, noisy_dir = scenes
    clean, noisy = (load_scene(DataConfig(path=str(d), downsample=1)) for d in scenes)
    a = np.stack([clean.image(c, f) for c in range(len(clean.cameras)) for f in range(clean.n_frames)]) * 255
    b = np.stack([noisy.image(c, f) for c in range(len(noisy.cameras)) for f in range(noisy.n_frames)]) * 255
    err = b - a
    mid = (a > 12) & (a < 243)  # 6 SDs from either end: nothing clipped
    assert mid.sum() > 5_000
    # both frames rounded: σ² + 1/12 (the noisy one's) + 1/12 (the clean one's, against the render)
    formula = 20 * math.log10(255 / SD) - 10 * math.log10(1 + (2 / 12) / SD**2)
    assert 10 * math.log10(255**2 / np.mean(err[mid] ** 2)) == pytest.approx(formula, abs=0.15)
    assert abs(err[mid].mean()) < 0.05
    cams = [err[i * clean.n_frames:(i + 1) * clean.n_frames].ravel() for i in range(len(clean.cameras))]
    assert abs(np.corrcoef(cams[0], cams[1])[0, 1]) < 0.05  # every camera its own noise
    meta = json.loads((noisy_dir / "known_size.json").read_text())
    # the black background clips half the noise away: a perfect model scores above the formula
    assert meta["params"]["noise_sd"] == SD and 20 * math.log10(255 / SD) - 0.2 < meta["noise_floor_psnr"] < 50
    assert "noise_sd" not in json.loads((clean_dir / "known_size.json").read_text())["params"]  # as before
    np.testing.assert_array_equal(np.load(clean_dir / "known_size.npz")["means"],
                                  np.load(noisy_dir / "known_size.npz")["means"])  # the same Gaussians


def test_noise_sd_is_checked() -> None:
    assert resolve({"noise_sd": 2}).noise_sd == 2 and resolve({}).noise_sd == 0
    with pytest.raises(InputError, match="noise_sd"):
        resolve({"noise_sd": -1})
