"""The colour-aligned PSNR's affine fit: least squares' answer (NumPy's ``lstsq`` as the oracle),
the same bits on every call, and flat renders handled."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ftgspp.colour_alignment import cholesky_solve, colour_aligned_np
from ftgspp.image_metrics import METRICS


def _oracle(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    x = np.concatenate([pred, np.ones((len(pred), 1))], axis=1)
    return np.clip(x @ np.linalg.lstsq(x, gt, rcond=None)[0], 0.0, 1.0)


def _frames(seed: int, n: int = 96 * 128) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    gt = rng.random((n, 3))
    m = np.eye(3) + 0.1 * rng.standard_normal((3, 3))
    pred = np.clip(gt @ m + 0.05 * rng.standard_normal(3) + 0.03 * rng.standard_normal((n, 3)), 0, 1)
    return pred, gt


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fit_matches_least_squares(seed: int) -> None:
    pred, gt = _frames(seed)
    np.testing.assert_allclose(colour_aligned_np(pred, gt), _oracle(pred, gt), rtol=0, atol=1e-11)


def test_low_contrast_render_still_matches_least_squares() -> None:
    pred, gt = _frames(3)
    dim = 0.5 + 0.01 * pred  # colours squeezed into 1 % of the range: a badly conditioned fit
    np.testing.assert_allclose(colour_aligned_np(dim, gt), _oracle(dim, gt), rtol=0, atol=1e-8)


def test_flat_grey_and_dark_renders_keep_least_squares_fitted_values() -> None:
    _, gt = _frames(4)
    flat = np.full_like(gt, 0.3)  # one colour: only the mean of gt can be fitted
    np.testing.assert_allclose(colour_aligned_np(flat, gt), np.broadcast_to(gt.mean(axis=0), gt.shape), atol=1e-12)
    grey = np.repeat(np.random.default_rng(5).random((len(gt), 1)), 3, axis=1)  # rank 2 with the constant
    np.testing.assert_allclose(colour_aligned_np(grey, gt), _oracle(grey, gt), atol=1e-10)
    pred, _ = _frames(5)
    dark = pred * np.array([1.0, 1.0, 1e-6])  # a faint but informative channel is kept
    np.testing.assert_allclose(colour_aligned_np(dark, gt), _oracle(dark, gt), atol=1e-10)
    a, kept = cholesky_solve(np.zeros((3, 3)), np.ones((3, 3)))
    assert not kept.any() and not a.any()


def test_non_finite_or_empty_input_gives_nan() -> None:
    pred, gt = _frames(8, n=50)
    for bad in (np.nan, np.inf):
        broken = pred.copy()
        broken[7, 1] = bad
        assert np.isnan(colour_aligned_np(broken, gt)).all() and np.isnan(colour_aligned_np(gt, broken)).all()
    assert colour_aligned_np(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0, 3)


def test_same_bits_on_every_call_whatever_the_memory_layout() -> None:
    pred, gt = _frames(6)
    first = colour_aligned_np(pred, gt)
    for shift in range(1, 4):  # the same values at other addresses, and in other layouts
        buf = np.empty(pred.size + shift)
        moved = buf[shift:].reshape(pred.shape)
        moved[:] = pred
        again = colour_aligned_np(moved, np.asfortranarray(gt))
        assert np.array_equal(first.view(np.uint64), again.view(np.uint64))
    wide = np.zeros((len(pred), 6))
    wide[:, ::2] = pred  # a strided view
    assert np.array_equal(first.view(np.uint64), colour_aligned_np(wide[:, ::2], gt).view(np.uint64))


def test_psnr_cc_is_reproducible_bit_for_bit() -> None:
    pred, gt = _frames(7)
    p = torch.from_numpy(pred.reshape(1, 96, 128, 3))
    g = torch.from_numpy(gt.reshape(1, 96, 128, 3))
    values = {float(METRICS["psnr_cc"].fn(p.clone(), g.clone(), {})) for _ in range(5)}
    assert len(values) == 1
