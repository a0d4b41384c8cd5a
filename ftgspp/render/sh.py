"""Real spherical harmonics (degree 0-3) in the 3DGS convention.

Colours are stored as SH coefficients per Gaussian and evaluated along the viewing
direction. The basis is the real SH basis ordered m = -l..l within each band, *with* the
Condon-Shortley phase kept (hence the minus signs on the degree-1 terms), exactly as in
the 3DGS / gsplat kernels. Evaluated colours are offset by 0.5 and clamped at 0, so an
all-zero coefficient set renders mid-grey and ``rgb_to_sh`` / ``sh_to_rgb`` convert the DC
term to and from RGB.

    colors = eval_sh(degree, sh, dirs)  # sh [N, K, 3], dirs [N, 3] -> [N, 3]
"""

from __future__ import annotations

import torch
from torch import Tensor

C0 = 0.28209479177387814  # 1 / (2 sqrt(pi))
C1 = 0.4886025119029199  # sqrt(3 / (4 pi))
C2 = (
    1.0925484305920792,
    -1.0925484305920792,
    0.31539156525252005,
    -1.0925484305920792,
    0.5462742152960396,
)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)

MAX_SH_DEGREE = 3


def num_sh_bases(degree: int) -> int:
    """Number of coefficients of an SH expansion up to ``degree``: (degree + 1)^2."""
    return (degree + 1) ** 2


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """Real SH basis functions up to ``degree`` at unit directions.

    dirs [N, 3] (normalised here) -> [N, (degree + 1)^2], ordered l = 0..degree, m = -l..l.
    """
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree must be in [0, {MAX_SH_DEGREE}], got {degree}")
    d = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)  # [N, 3]
    x, y, z = d.unbind(-1)  # [N] each
    basis = [torch.full_like(x, C0)]
    if degree >= 1:
        basis += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        basis += [
            C2[0] * x * y,
            C2[1] * y * z,
            C2[2] * (2.0 * zz - xx - yy),
            C2[3] * x * z,
            C2[4] * (xx - yy),
        ]
    if degree >= 3:
        basis += [
            C3[0] * y * (3.0 * xx - yy),
            C3[1] * x * y * z,
            C3[2] * y * (4.0 * zz - xx - yy),
            C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            C3[4] * x * (4.0 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(basis, dim=-1)  # [N, (degree + 1)^2]


def eval_sh(degree: int, sh: Tensor, dirs: Tensor) -> Tensor:
    """Colours from SH coefficients along viewing directions (3DGS convention).

    degree: active degree; only the first (degree + 1)^2 of the K coefficients are used.
    sh: [N, K, D] coefficients, K >= (degree + 1)^2 (D = 3 for RGB).
    dirs: [N, 3] viewing directions (Gaussian centre minus camera centre; need not be unit).
    Returns [N, D] = max(sum_k basis_k(dirs) sh[:, k] + 0.5, 0).
    """
    n_bases = num_sh_bases(degree)
    if sh.shape[-2] < n_bases:
        raise ValueError(f"degree {degree} needs {n_bases} SH coefficients, got {sh.shape[-2]}")
    basis = sh_basis(degree, dirs)  # [N, B]
    rgb = (basis.unsqueeze(-1) * sh[:, :n_bases]).sum(dim=-2)  # [N, D]
    return (rgb + 0.5).clamp_min(0.0)


def rgb_to_sh(rgb: Tensor) -> Tensor:
    """DC coefficient that renders ``rgb`` (any shape) under ``eval_sh``."""
    return (rgb - 0.5) / C0


def sh_to_rgb(sh: Tensor) -> Tensor:
    """Colour rendered by a DC coefficient ``sh`` (any shape), before clamping."""
    return sh * C0 + 0.5
