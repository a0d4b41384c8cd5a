"""The least-squares affine colour map of the colour-aligned PSNR, with the same bits every time.

``torch.linalg.lstsq`` (LAPACK's QR-based solvers through MKL or OpenBLAS) gave solutions that
differed in their last bits between evaluations of one model in one process, so ``psnr_cc``
did too (docs/benchmarks-history.md, session 38). Here the fit is the normal equations
``[x 1]ᵀ[x 1] A = [x 1]ᵀ y`` summed in float64 over the pixels in their order, solved by a
Cholesky factorisation that drops a column the earlier ones already explain (a flat or grey
render: its coefficient is 0, and the fitted values, unique whatever the coefficients, are
unchanged), and applied pixel by pixel, all in Numba without fast-math: the same inputs give
the same bits on any machine and at any thread count. The fitted values are those of least
squares (tested against ``numpy.linalg.lstsq``). A render or ground truth with NaN or infinity
gives NaN.

    from ftgspp.colour_alignment import colour_aligned_np
    aligned = colour_aligned_np(pred, gt)   # [P, 3] float64 each -> [P, 3], clamped to [0, 1]
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ftgspp.runtime.jit import JIT

DEPENDENT = 1e-9  # a column this fraction or less unexplained by the earlier ones is dropped


@njit(**JIT)
def normal_equations(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(G [4, 4], R [4, 3])`` = (``Xᵀ X``, ``Xᵀ y``) with ``X = [x, 1]``, each entry summed in
    pixel order (in registers: G's 10 distinct entries and R's 12). x, y [P, 3] float64."""
    rr = rg = rb = gg = gb = bb = sr = sg = sb = 0.0
    yr0 = yr1 = yr2 = yg0 = yg1 = yg2 = yb0 = yb1 = yb2 = y0 = y1 = y2 = 0.0
    for p in range(x.shape[0]):
        r, g, b = x[p, 0], x[p, 1], x[p, 2]
        t0, t1, t2 = y[p, 0], y[p, 1], y[p, 2]
        rr += r * r
        rg += r * g
        rb += r * b
        gg += g * g
        gb += g * b
        bb += b * b
        sr += r
        sg += g
        sb += b
        yr0 += r * t0
        yr1 += r * t1
        yr2 += r * t2
        yg0 += g * t0
        yg1 += g * t1
        yg2 += g * t2
        yb0 += b * t0
        yb1 += b * t1
        yb2 += b * t2
        y0 += t0
        y1 += t1
        y2 += t2
    n = float(x.shape[0])
    gram = np.array([[rr, rg, rb, sr], [rg, gg, gb, sg], [rb, gb, bb, sb], [sr, sg, sb, n]])
    rhs = np.array([[yr0, yr1, yr2], [yg0, yg1, yg2], [yb0, yb1, yb2], [y0, y1, y2]])
    return gram, rhs


@njit(**JIT)
def cholesky_solve(g: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(A, kept)``: a least-squares solution of ``G A = R`` for a symmetric positive
    semi-definite ``G`` [n, n] (``R`` [n, m]) by Cholesky, in index order. An index whose pivot
    is at most ``DEPENDENT`` of its diagonal entry (or whose entry is not positive) depends on
    the earlier ones: it is dropped (``kept`` False) and its row of ``A`` is 0."""
    n, m = g.shape[0], r.shape[1]
    low = np.zeros((n, n))
    kept = np.zeros(n, np.bool_)
    for j in range(n):
        d = g[j, j]
        for k in range(j):
            d -= low[j, k] * low[j, k]
        if not (g[j, j] > 0.0 and d > DEPENDENT * g[j, j]):  # also catches NaN
            continue  # column j of low stays 0
        kept[j] = True
        low[j, j] = np.sqrt(d)
        for i in range(j + 1, n):
            s = g[i, j]
            for k in range(j):
                s -= low[i, k] * low[j, k]
            low[i, j] = s / low[j, j]
    a = np.zeros((n, m))
    z = np.zeros(n)
    for c in range(m):
        for i in range(n):  # L z = r over the kept indices
            if kept[i]:
                s = r[i, c]
                for k in range(i):
                    s -= low[i, k] * z[k]
                z[i] = s / low[i, i]
        for i in range(n - 1, -1, -1):  # Lᵀ a = z
            if kept[i]:
                s = z[i]
                for k in range(i + 1, n):
                    s -= low[k, i] * a[k, c]
                a[i, c] = s / low[i, i]
    return a, kept


@njit(**JIT)
def apply_affine(x: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``clamp([x, 1] A, 0, 1)``, each value summed in the order r, g, b, 1. x [P, 3], A [4, 3]."""
    out = np.empty_like(x)
    for p in range(x.shape[0]):
        for c in range(3):
            v = x[p, 0] * a[0, c] + x[p, 1] * a[1, c] + x[p, 2] * a[2, c] + a[3, c]
            out[p, c] = min(max(v, 0.0), 1.0)
    return out


def colour_aligned_np(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """``pred`` [P, 3] after the least-squares affine colour map onto ``gt`` [P, 3], clamped to
    [0, 1]; all NaN when either holds a NaN or an infinity, or has no pixels."""
    x = np.ascontiguousarray(pred, dtype=np.float64)
    y = np.ascontiguousarray(gt, dtype=np.float64)
    if len(x) == 0 or not (np.isfinite(x).all() and np.isfinite(y).all()):
        return np.full(x.shape, np.nan)
    g, r = normal_equations(x, y)
    a, _ = cholesky_solve(g, r)
    return apply_affine(x, a)
