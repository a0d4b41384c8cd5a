"""Spherical harmonics: basis against SciPy, orthonormality, rotation invariance, colour rules."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.special import eval_legendre, sph_harm_y

from ftgspp.render.sh import eval_sh, num_sh_bases, rgb_to_sh, sh_basis, sh_to_rgb


def random_dirs(n: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(n, 3, generator=g, dtype=torch.float64)
    return d / d.norm(dim=-1, keepdim=True)


def scipy_real_sh(l: int, m: int, dirs: np.ndarray) -> np.ndarray:
    """Real SH as used by 3DGS, from SciPy's complex Y_l^m (Condon-Shortley phase kept)."""
    theta = np.arccos(np.clip(dirs[:, 2], -1.0, 1.0))  # polar
    phi = np.mod(np.arctan2(dirs[:, 1], dirs[:, 0]), 2 * np.pi)  # azimuth
    y = sph_harm_y(l, abs(m), theta, phi)
    if m > 0:
        return np.sqrt(2.0) * y.real
    if m < 0:
        return np.sqrt(2.0) * y.imag
    return y.real


def test_basis_matches_scipy() -> None:
    dirs = random_dirs(200)
    basis = sh_basis(3, dirs).numpy()  # [200, 16]
    col = 0
    for l in range(4):
        for m in range(-l, l + 1):
            np.testing.assert_allclose(basis[:, col], scipy_real_sh(l, m, dirs.numpy()), atol=1e-12)
            col += 1


def test_basis_is_orthonormal_on_the_sphere() -> None:
    # Gauss-Legendre in cos(theta) x uniform phi integrates these polynomials exactly.
    nodes, weights = np.polynomial.legendre.leggauss(12)
    phi = np.arange(24) * (2 * np.pi / 24)
    ct, ph = np.meshgrid(nodes, phi, indexing="ij")
    st = np.sqrt(1 - ct**2)
    dirs = np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1).reshape(-1, 3)
    w = (weights[:, None] * np.full_like(ph, 2 * np.pi / 24)).reshape(-1)
    basis = sh_basis(3, torch.from_numpy(dirs)).numpy()  # [Q, 16]
    gram = basis.T @ (w[:, None] * basis)
    np.testing.assert_allclose(gram, np.eye(16), atol=1e-12)


def test_band_energy_is_rotation_invariant() -> None:
    # Addition theorem: sum_m Y_lm(u) Y_lm(v) = (2l + 1) / (4 pi) P_l(u . v).
    u, v = random_dirs(50, seed=1), random_dirs(50, seed=2)
    bu, bv = sh_basis(3, u), sh_basis(3, v)
    cos = (u * v).sum(-1).numpy()
    for l in range(4):
        band = slice(l * l, (l + 1) ** 2)
        lhs = (bu[:, band] * bv[:, band]).sum(-1).numpy()
        np.testing.assert_allclose(lhs, (2 * l + 1) / (4 * np.pi) * eval_legendre(l, cos), atol=1e-12)


def test_eval_sh_uses_first_coefficients_offsets_and_clamps() -> None:
    n = 64
    g = torch.Generator().manual_seed(3)
    sh = torch.randn(n, 16, 3, generator=g, dtype=torch.float64)
    dirs = random_dirs(n, seed=4) * 3.7  # not unit: eval_sh normalises
    for degree in range(4):
        k = num_sh_bases(degree)
        expected = torch.einsum("nk,nkc->nc", sh_basis(degree, dirs), sh[:, :k]) + 0.5
        torch.testing.assert_close(eval_sh(degree, sh, dirs), expected.clamp_min(0.0))
        # Coefficients above the active degree are ignored.
        torch.testing.assert_close(eval_sh(degree, sh[:, :k], dirs), eval_sh(degree, sh, dirs))
    assert (eval_sh(3, sh, dirs) >= 0).all() and (eval_sh(3, sh, dirs) == 0).any()


def test_dc_roundtrip_renders_the_same_colour_from_every_direction() -> None:
    rgb = torch.rand(10, 3, dtype=torch.float64)
    sh = torch.zeros(10, 16, 3, dtype=torch.float64)
    sh[:, 0] = rgb_to_sh(rgb)
    for seed in range(3):
        torch.testing.assert_close(eval_sh(3, sh, random_dirs(10, seed)), rgb)
    torch.testing.assert_close(sh_to_rgb(rgb_to_sh(rgb)), rgb)


def test_bad_degree_is_rejected() -> None:
    with pytest.raises(ValueError):
        eval_sh(2, torch.zeros(1, 4, 3), torch.ones(1, 3))
    with pytest.raises(ValueError):
        sh_basis(4, torch.ones(1, 3))
