"""The Numba training-loss SSIM (``ftgspp.ssim_cpu``) against PyTorch autograd and scipy.

Oracles: the grouped-convolution SSIM of ``metrics`` evaluated and differentiated in float64
by PyTorch autograd, and scipy's zero-padded Gaussian filter (in test_image_metrics.py).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ftgspp.image_metrics import SSIM_WINDOW, _nchw, _ssim_map, ssim_same
from ftgspp.ssim_cpu import RADIUS
from tests.numba_threads import under_thread_counts


def autograd_ssim_same(a: torch.Tensor, b: torch.Tensor, data_range: float) -> torch.Tensor:
    """The PyTorch path of ``ssim_same`` for [B, H, W, C] inputs -> [B]."""
    return _ssim_map(_nchw(a), _nchw(b), data_range, padding=SSIM_WINDOW // 2).flatten(1).mean(dim=1)


def pair(shape, seed):
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(*shape, generator=g)
    b = (0.6 * a + 0.4 * torch.rand(*shape, generator=g)).clamp(0, 1)
    b[..., : shape[-2] // 3, :] = 0.5  # a flat patch: tiny variances, where rounding matters most
    return a, b


@pytest.mark.parametrize("shape", [(2, 40, 53, 3), (1, 13, 11, 1), (1, 5, 7, 3), (3, 17, 12, 2)])
@pytest.mark.parametrize("data_range", [1.0, 2.0])
def test_values_and_gradients_match_float64_autograd(shape, data_range) -> None:
    a, b = pair(shape, sum(shape))
    a32, b32 = a.clone().requires_grad_(True), b.clone().requires_grad_(True)
    got = ssim_same(a32, b32, data_range)
    weights = torch.linspace(0.5, 1.5, shape[0])
    (got * weights).sum().backward()
    a64, b64 = a.double().requires_grad_(True), b.double().requires_grad_(True)
    want = autograd_ssim_same(a64, b64, data_range)
    (want * weights.double()).sum().backward()
    assert got.dtype == torch.float32 and got.shape == (shape[0],)
    torch.testing.assert_close(got.double(), want.detach(), rtol=0, atol=2e-6)
    for name, g, ref in (("a", a32.grad, a64.grad), ("b", b32.grad, b64.grad)):
        err = (g.double() - ref).abs().max().item()
        assert err <= 1e-4 * ref.abs().max().item(), f"grad {name}: {err:.3g}"


def test_unbatched_image_gives_a_scalar_and_only_requested_gradients() -> None:
    a, b = pair((1, 20, 24, 3), 0)
    pred = a[0].clone().requires_grad_(True)
    value = ssim_same(pred, b[0])
    assert value.shape == ()
    (1 - value).backward()
    assert pred.grad is not None and pred.grad.abs().sum() > 0
    with torch.no_grad():
        assert float(ssim_same(a[0], a[0])) == pytest.approx(1.0, abs=1e-6)


def test_bitwise_deterministic_across_thread_counts() -> None:
    a, b = pair((2, 33, 41, 3), 5)

    def once():
        x = a.clone().requires_grad_(True)
        value = ssim_same(x, b)
        value.sum().backward()
        return value.detach(), x.grad

    results = under_thread_counts(once)
    for value, grad in results[1:]:
        assert torch.equal(value, results[0][0]) and torch.equal(grad, results[0][1])


def _row_passes(src: np.ndarray, taps: np.ndarray, n_ch: int) -> np.ndarray:
    """The zero-padded filter as eleven float32 passes, one tap each, in tap order (NumPy)."""
    out = np.zeros_like(src)
    for k, w in enumerate(taps):
        off = (k - RADIUS) * n_ch
        j0, j1 = max(0, -off), min(len(src), len(src) - off)
        if j1 > j0:
            out[j0:j1] += w * src[j0 + off : j1 + off]
    return out


def _awkward(shape: tuple[int, ...], seed: int) -> np.ndarray:
    """Signed float32 values with -0.0, NaN and infinities among them."""
    rng = np.random.default_rng(seed)
    x = (rng.standard_normal(shape) * 3).astype(np.float32)
    flat = x.reshape(-1)
    picks = rng.choice(flat.size, size=min(flat.size, 6), replace=False)
    flat[picks] = np.array([-0.0, 0.0, np.nan, np.inf, -np.inf, 1e-30], np.float32)[: len(picks)]
    return x


@pytest.mark.parametrize("width,n_ch", [(3, 1), (7, 3), (12, 2), (40, 3), (11, 1)])
def test_filters_add_the_taps_bit_for_bit_as_one_pass_per_tap(width: int, n_ch: int) -> None:
    """The register-summed filters give the bits of adding one tap at a time (the earlier kernels'
    order), the padding's zeros included, on signed values with -0.0, NaN and infinities."""
    from ftgspp.image_metrics import _gaussian_1d
    from ftgspp.ssim_cpu import _filter_column, _filter_row, _padded

    taps = _gaussian_1d(SSIM_WINDOW, 1.5, torch.float32, "cpu").numpy()
    rows = _awkward((17, width * n_ch), width)
    for r in range(len(rows)):
        got = np.empty_like(rows[r])
        _filter_row(rows[r], got, taps, n_ch, _padded(rows.shape[1], n_ch))
        assert np.array_equal(got.view(np.uint32), _row_passes(rows[r], taps, n_ch).view(np.uint32)), r
    maps = _awkward((2, 2 * 17, width * n_ch), width + 1)  # two images of 17 rows each
    for r in range(maps.shape[1]):
        got = np.empty((2, maps.shape[2]), np.float32)
        _filter_column(maps, r, 17, taps, got)
        top = r - r % 17
        want = np.zeros_like(got)
        for k, w in enumerate(taps):
            src_row = r + k - RADIUS
            if top <= src_row < top + 17:
                want += w * maps[:, src_row]
        assert np.array_equal(got.view(np.uint32), want.view(np.uint32)), r


def test_taps_other_than_eleven_float32_are_refused() -> None:
    from ftgspp.ssim_cpu import ssim_same_cpu

    a = torch.rand(1, 16, 16, 3)
    with pytest.raises(ValueError, match="taps must be float32"):
        ssim_same_cpu(a, a, np.ones(11, np.float64) / 11, 1e-4, 9e-4)
