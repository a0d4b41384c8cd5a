"""Training-loss SSIM on the CPU: separable 11-tap Gaussian filtering in Numba, hand-written backward.

Computes exactly what ``image_metrics.ssim_same`` defines (zero-padded 'same' Gaussian window,
sigma 1.5, population covariances, mean over every pixel and channel), in float32, to float32
rounding of the PyTorch version, without PyTorch's grouped-convolution autograd graph:

- forward: one horizontal pass filters x, y, x^2, y^2 and xy along each image row (an image
  [H, W, C] is a grid of H rows of W*C floats; a shift of one pixel is a shift of C floats),
  one vertical pass finishes the five local moments and evaluates the SSIM map. With
  gradients requested it also stores the map's partial derivatives with respect to the
  moments (dS/dmu_x, dS/dmu_y, dS/dsigma^2 terms, dS/dsigma_xy).
- backward: the zero-padded filter with symmetric taps is its own adjoint, so
  dL/dx = f(dS/dmu_x) + 2 x f(dS/dE[x^2]) + y f(dS/dE[xy]) (and symmetrically for y), with f
  the same separable filter.

Every row is computed by one thread and each image's mean is a fixed-order sum of float64
row sums, so results are bitwise identical across runs and thread counts.

    from ftgspp.ssim_cpu import ssim_same_cpu
    value = ssim_same_cpu(pred, gt)  # [H, W, C] -> scalar, or [B, H, W, C] -> [B]
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange
from torch import Tensor

from ftgspp.runtime.jit import JIT, configure_numba

RADIUS = 5  # 11 taps


@njit(**JIT)
def _filter_padded(pad, dst, taps, n_ch):
    """dst[j] = taps (*) the row that ``pad`` holds from offset RADIUS * n_ch on, with zeros
    around it (``_padded``): sum over k = 0..10 of taps[k] * pad[j + k n_ch], summed from 0 in
    that order, kept in a register. Adding the padding's zero products leaves every partial sum
    as it was, so the values are those of skipping the taps that fall off the row. The indices
    are unsigned: LLVM then needs no negative-index fix-up and vectorises over j."""
    c = np.uintp(n_ch)
    w0, w1, w2, w3, w4, w5, w6, w7, w8, w9, w10 = (taps[0], taps[1], taps[2], taps[3], taps[4], taps[5],
                                                   taps[6], taps[7], taps[8], taps[9], taps[10])  # fmt: skip
    for i in range(dst.shape[0]):
        j = np.uintp(i)
        acc = np.float32(0.0)
        acc += w0 * pad[j]
        acc += w1 * pad[j + c]
        acc += w2 * pad[j + np.uintp(2) * c]
        acc += w3 * pad[j + np.uintp(3) * c]
        acc += w4 * pad[j + np.uintp(4) * c]
        acc += w5 * pad[j + np.uintp(5) * c]
        acc += w6 * pad[j + np.uintp(6) * c]
        acc += w7 * pad[j + np.uintp(7) * c]
        acc += w8 * pad[j + np.uintp(8) * c]
        acc += w9 * pad[j + np.uintp(9) * c]
        acc += w10 * pad[j + np.uintp(10) * c]
        dst[j] = acc


@njit(**JIT)
def _padded(length, n_ch):
    """Scratch for ``_filter_padded``: a row of ``length`` with RADIUS pixels of zeros each side."""
    return np.zeros(length + 2 * RADIUS * n_ch, np.float32)


@njit(**JIT)
def _filter_row(src, dst, taps, n_ch, pad):
    """dst = taps (*) src along one row of W*C floats, zero padded, channel stride n_ch."""
    o = np.uintp(RADIUS * n_ch)
    for i in range(src.shape[0]):  # a loop, not a slice assignment: Numba's is element by element
        j = np.uintp(i)  # unsigned, as in _filter_padded: LLVM then vectorises the copy (it was scalar)
        pad[o + j] = src[j]
    _filter_padded(pad, dst, taps, n_ch)


@njit(**JIT)
def _filter_column(src, r, height, taps, out):
    """out[q] = taps (*) src[q] down the image column at row r (zero padded at the image's
    top and bottom; rows of one image are consecutive, ``height`` of them). src [Q, rows, L].

    Away from the top and bottom, each value is the eleven products summed from 0 in tap order
    in a register (unsigned indices into one array, so LLVM vectorises over the row); near them,
    the taps inside the image are added in the same order, row by row."""
    top = r - r % height
    if r - RADIUS >= top and r + RADIUS < top + height:
        w0, w1, w2, w3, w4, w5, w6, w7, w8, w9, w10 = (taps[0], taps[1], taps[2], taps[3], taps[4], taps[5],
                                                       taps[6], taps[7], taps[8], taps[9], taps[10])  # fmt: skip
        r0 = np.uintp(r - RADIUS)
        one = np.uintp(1)
        for q in range(src.shape[0]):
            s = src[q]
            o = out[q]
            for i in range(o.shape[0]):
                j = np.uintp(i)
                acc = np.float32(0.0)
                acc += w0 * s[r0, j]
                acc += w1 * s[r0 + one, j]
                acc += w2 * s[r0 + np.uintp(2), j]
                acc += w3 * s[r0 + np.uintp(3), j]
                acc += w4 * s[r0 + np.uintp(4), j]
                acc += w5 * s[r0 + np.uintp(5), j]
                acc += w6 * s[r0 + np.uintp(6), j]
                acc += w7 * s[r0 + np.uintp(7), j]
                acc += w8 * s[r0 + np.uintp(8), j]
                acc += w9 * s[r0 + np.uintp(9), j]
                acc += w10 * s[r0 + np.uintp(10), j]
                o[j] = acc
        return
    out[:] = 0.0
    for k in range(taps.shape[0]):
        src_row = r + k - RADIUS
        if src_row < top or src_row >= top + height:
            continue
        w = taps[k]
        for q in range(src.shape[0]):
            o = out[q]
            s = src[q, src_row]
            for j in range(o.shape[0]):
                o[j] += w * s[j]


@njit(parallel=True, **JIT)
def ssim_forward(
    x: np.ndarray,  # [B * H, W * C] float32
    y: np.ndarray,  # [B * H, W * C] float32
    height: int,
    n_ch: int,
    taps: np.ndarray,  # [11] float32, normalised Gaussian
    c1: np.float32,
    c2: np.float32,
    want_grad: bool,
):
    """Row sums of the SSIM map [B * H] float64 and, with ``want_grad``, its partial derivatives
    with respect to mu_x, mu_y, E[x^2] (= that w.r.t. E[y^2]) and E[xy], each [B * H, W * C]."""
    rows, length = x.shape
    hx = np.empty((5, rows, length), np.float32)  # horizontally filtered x, y, xx, yy, xy
    o = np.uintp(RADIUS * n_ch)
    for r in prange(rows):
        pad = _padded(length, n_ch)
        xr, yr = x[r], y[r]
        _filter_row(xr, hx[0, r], taps, n_ch, pad)
        _filter_row(yr, hx[1, r], taps, n_ch, pad)
        for i in range(length):  # unsigned indices (_filter_row)
            j = np.uintp(i)
            pad[o + j] = xr[j] * xr[j]
        _filter_padded(pad, hx[2, r], taps, n_ch)
        for i in range(length):
            j = np.uintp(i)
            pad[o + j] = yr[j] * yr[j]
        _filter_padded(pad, hx[3, r], taps, n_ch)
        for i in range(length):
            j = np.uintp(i)
            pad[o + j] = xr[j] * yr[j]
        _filter_padded(pad, hx[4, r], taps, n_ch)
    n_maps = 4 if want_grad else 0
    partials = np.empty((n_maps, rows if want_grad else 0, length), np.float32)
    row_sums = np.empty(rows, np.float64)
    two = np.float32(2.0)
    for r in prange(rows):
        m = np.empty((5, length), np.float32)
        smap = np.empty(length, np.float32)  # the row of the SSIM map, summed below
        _filter_column(hx, r, height, taps, m)
        # the map's loop is free of the float64 sum, so LLVM vectorises it (same values)
        for j in range(length):
            mx, my = m[0, j], m[1, j]
            vx = m[2, j] - mx * mx
            vy = m[3, j] - my * my
            vxy = m[4, j] - mx * my
            a1 = two * mx * my + c1
            a2 = two * vxy + c2
            b1 = mx * mx + my * my + c1
            b2 = vx + vy + c2
            s = (a1 * a2) / (b1 * b2)
            smap[j] = s
            if want_grad:
                inv = np.float32(1.0) / (b1 * b2)
                d_a1 = a2 * inv
                d_a2 = a1 * inv
                d_b1 = -s / b1
                d_b2 = -s / b2
                # a1 = 2 mx my + c1, a2 = 2 (Exy - mx my) + c2, b1 = mx^2 + my^2 + c1,
                # b2 = Exx - mx^2 + Eyy - my^2 + c2
                partials[0, r, j] = two * (my * (d_a1 - d_a2) + mx * (d_b1 - d_b2))
                partials[1, r, j] = two * (mx * (d_a1 - d_a2) + my * (d_b1 - d_b2))
                partials[2, r, j] = d_b2
                partials[3, r, j] = two * d_a2
        total = 0.0
        for j in range(length):  # float64, in pixel order
            total += smap[j]
        row_sums[r] = total
    return row_sums, partials


@njit(parallel=True, **JIT)
def ssim_backward(
    x: np.ndarray,  # [B * H, W * C] float32
    y: np.ndarray,  # [B * H, W * C] float32
    height: int,
    n_ch: int,
    taps: np.ndarray,  # [11] float32
    partials: np.ndarray,  # [4, B * H, W * C] from ssim_forward
    row_scale: np.ndarray,  # [B * H] float32, d loss / d (each map value) of the row's image
    want_x: bool,
    want_y: bool,
):
    """Gradients w.r.t. x and y ([B * H, W * C] float32; empty when not wanted)."""
    rows, length = x.shape
    hp = np.empty((4, rows, length), np.float32)
    for r in prange(rows):
        pad = _padded(length, n_ch)
        for q in range(4):
            _filter_row(partials[q, r], hp[q, r], taps, n_ch, pad)
    gx = np.empty((rows if want_x else 0, length), np.float32)
    gy = np.empty((rows if want_y else 0, length), np.float32)
    two = np.float32(2.0)
    for r in prange(rows):
        f = np.empty((4, length), np.float32)  # filtered partials at this row
        _filter_column(hp, r, height, taps, f)
        scale = row_scale[r]
        for j in range(length):
            if want_x:
                gx[r, j] = scale * (f[0, j] + two * x[r, j] * f[2, j] + y[r, j] * f[3, j])
            if want_y:
                gy[r, j] = scale * (f[1, j] + two * y[r, j] * f[2, j] + x[r, j] * f[3, j])
    return gx, gy


class _SSIMSame(torch.autograd.Function):
    """``ssim_forward`` / ``ssim_backward`` as one autograd node. a, b [B, H, W, C] float32."""

    @staticmethod
    def forward(ctx, a, b, taps, c1, c2):
        batch, height, width, n_ch = a.shape
        x = np.ascontiguousarray(a.detach().numpy()).reshape(batch * height, width * n_ch)
        y = np.ascontiguousarray(b.detach().numpy()).reshape(batch * height, width * n_ch)
        want = bool(ctx.needs_input_grad[0] or ctx.needs_input_grad[1])
        row_sums, partials = ssim_forward(x, y, height, n_ch, taps, np.float32(c1), np.float32(c2), want)
        means = row_sums.reshape(batch, height).sum(axis=1) / (height * width * n_ch)
        ctx.arrays = (x, y, partials, taps)
        ctx.shape = (batch, height, width, n_ch)
        return torch.from_numpy(means.astype(np.float32))

    @staticmethod
    def backward(ctx, grad):
        x, y, partials, taps = ctx.arrays
        batch, height, width, n_ch = ctx.shape
        per_value = grad.detach().to(torch.float32).numpy() / np.float32(height * width * n_ch)  # [B]
        row_scale = np.repeat(per_value, height).astype(np.float32)
        want_x, want_y = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        gx, gy = ssim_backward(x, y, height, n_ch, taps, partials, row_scale, want_x, want_y)
        shape = (batch, height, width, n_ch)
        return (
            torch.from_numpy(gx).reshape(shape) if want_x else None,
            torch.from_numpy(gy).reshape(shape) if want_y else None,
            None,
            None,
            None,
        )


def ssim_same_cpu(a: Tensor, b: Tensor, taps: np.ndarray, c1: float, c2: float) -> Tensor:
    """SSIM with a zero-padded 'same' window per image: a, b [B, H, W, C] float32 CPU -> [B].

    ``taps`` [11] float32 is the normalised 1-D Gaussian; ``c1``, ``c2`` the SSIM constants.
    """
    if taps.dtype != np.float32 or taps.shape != (2 * RADIUS + 1,):  # the kernels sum 11 float32 products
        raise ValueError(f"taps must be float32 of shape ({2 * RADIUS + 1},), got {taps.dtype} {taps.shape}")
    configure_numba()  # before the first parallel kernel fixes Numba's threading layer
    return _SSIMSame.apply(a.contiguous(), b.contiguous(), taps, c1, c2)
