"""LPIPS-Alex on the reference pairs against an independent float64 NumPy computation.

No published AlexNet distance exists for ex_ref/ex_p0/ex_p1, so the oracle is the LPIPS
v0.1 definition computed a second way: AlexNet's five conv+ReLU taps written with NumPy
(``sliding_window_view`` + ``tensordot``, float64), max-pooling by windowed max, channel
unit-normalisation, the non-negative 1x1 heads and the spatial mean. It shares only the
weights with ``ftgspp.lpips`` (whose conversion the published VGG distances check).
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view
from test_lpips import LPIPS_REF_DIR

from ftgspp.image_metrics import lpips_distance, read_image
from ftgspp.lpips.nets import LPIPS_SCALE, LPIPS_SHIFT

# (stride, padding, max-pool 3/2 before this conv) of AlexNet's five convolutions
ALEX_LAYERS = ((4, 2, False), (1, 2, True), (1, 1, True), (1, 1, False), (1, 1, False))


def conv2d(x: np.ndarray, w: np.ndarray, b: np.ndarray, stride: int, pad: int) -> np.ndarray:
    """x [C, H, W], w [O, C, k, k] -> [O, H', W'] (cross-correlation, zero padding)."""
    k = w.shape[-1]
    xp = np.pad(x, ((0, 0), (pad, pad), (pad, pad)))
    win = sliding_window_view(xp, (k, k), axis=(1, 2))[:, ::stride, ::stride]  # [C, H', W', k, k]
    return np.tensordot(w, win, axes=([1, 2, 3], [0, 3, 4])) + b[:, None, None]


def max_pool(x: np.ndarray, k: int = 3, s: int = 2) -> np.ndarray:
    return sliding_window_view(x, (k, k), axis=(1, 2))[:, ::s, ::s].max(axis=(-1, -2))


def alex_lpips_numpy(img0: np.ndarray, img1: np.ndarray, sd: dict[str, np.ndarray]) -> float:
    """LPIPS v0.1 (AlexNet) of two [H, W, 3] images in [0, 1], inputs mapped to [-1, 1]."""
    shift, scale = np.array(LPIPS_SHIFT)[:, None, None], np.array(LPIPS_SCALE)[:, None, None]
    feats = []
    for img in (img0, img1):
        x = ((2.0 * img.transpose(2, 0, 1) - 1.0) - shift) / scale
        taps = []
        for i, (stride, pad, pool) in enumerate(ALEX_LAYERS):
            if pool:
                x = max_pool(x)
            x = np.maximum(conv2d(x, sd[f"net.convs.{i}.weight"], sd[f"net.convs.{i}.bias"], stride, pad), 0.0)
            taps.append(x)
        feats.append(taps)
    total = 0.0
    for i, (a, b) in enumerate(zip(*feats)):
        na = a / (np.sqrt((a**2).sum(0, keepdims=True)) + 1e-10)
        nb = b / (np.sqrt((b**2).sum(0, keepdims=True)) + 1e-10)
        w = sd[f"lins.{i}.weight"].reshape(-1)  # [C]
        total += float(np.tensordot(w, (na - nb) ** 2, axes=(0, 0)).mean())
    return total


@pytest.mark.parametrize("pair", ["p0", "p1"])
def test_alex_matches_an_independent_numpy_computation(lpips_models, pair):
    model = lpips_models["alex"]
    sd = {k: v.detach().double().numpy() for k, v in model.state_dict().items()}
    ref, other = read_image(LPIPS_REF_DIR / "ex_ref.png"), read_image(LPIPS_REF_DIR / f"ex_{pair}.png")
    expected = alex_lpips_numpy(ref.double().numpy(), other.double().numpy(), sd)
    got = float(lpips_distance(model, ref, other))
    print(f"lpips_alex ref-{pair}: torch {got:.6f}, numpy float64 {expected:.6f}")
    assert got == pytest.approx(expected, rel=1e-5, abs=1e-6)


@pytest.mark.parametrize("net", ["alex", "vgg"])
def test_lpips_min_side_is_what_the_network_can_take(lpips_models, net):
    """``LPIPS_MIN_SIDE`` is the real limit: the network runs at that size and fails one below
    (which is why evaluation reports NaN there instead of calling it)."""
    import torch

    from ftgspp.image_metrics import LPIPS_MIN_SIDE

    side = LPIPS_MIN_SIDE[net]
    model = lpips_models[net]
    ok = torch.rand(1, 3, side, side + 7)
    assert torch.isfinite(model(ok, ok.flip(-1))).all()
    with pytest.raises(RuntimeError):
        small = torch.rand(1, 3, side - 1, side + 7)
        model(small, small)
