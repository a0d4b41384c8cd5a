"""Numba kernels of the fused per-Gaussian stage, the parts every method shares: SH colour and EWA
projection, forward and backward, one block of Gaussians at a time.

A method's fused kernel pair (``render.prepare``: ``FusedKernels``) allocates the forward's
outputs (``forward_outputs``), runs over blocks in parallel (``block_rows``: a block's Gaussians
and scratch rows), evaluates each block's Gaussians at time t in its own loop, writes each one's
centre, quaternion and log scales into the block's scratch rows (``gaussian_row``; in the
forward pass also its opacity, ``opacity_row``), and
hands the block to ``projection`` (forward) or ``projection_backward`` (backward). A method
whose colour is SH then hands it to ``sh_colour`` (forward) or ``sh_colour_backward``
(backward, after the projection's); a method with view-independent RGB copies its colour and
its cotangent itself. Together they compute what the method's ``at_time``, ``sh.eval_sh``
(along the normalised direction from the camera centre) and ``project.project`` compute with
dozens of PyTorch operations, in float32 and in the same order of operations as those modules,
so that the outputs agree with them to float32 rounding:

    colour = max(sum_k Y_k(dir) sh_k + 0.5, 0)
    means2d, conics, depths, radii  as in ``project.py`` (culled Gaussians: zeros, radii 0;
                                    the opacity-aware radii of ``contract.py``)

The backward recomputes the forward values of each Gaussian and applies the chain rule by hand
(the derivation is written next to each step), leaving the cotangent of each centre at time t
(the projection's and the SH colour's) in the rows ``ROW_GMX`` .. ``ROW_GMZ``, and that of its
quaternion at time t in ``gr_quats``, for the method's own chain rule through time. Each
Gaussian's gradients are computed by one thread with no reduction across Gaussians, so results
are bitwise identical across runs and thread counts.

Each block of ``BLOCK`` Gaussians goes through three loops: the library calls (exp, log) one
Gaussian at a time (the method's loop), writing one 1D array per quantity into the block's own
scratch rows; the projection (``_project_block``, and its chain rule in two loops), arithmetic
only, which LLVM vectorises across Gaussians; the SH colour, if any. Lanes never reorder the
arithmetic (no fast-math), so every non-NaN result has the bits a scalar loop gives it, on
every target. A NaN result is NaN in the same places, but its payload and sign bits depend on
the instructions LLVM chose (vector lanes or the scalar remainder, a fresh compile or a cached
one), as they already did between targets: the guarantee leaves them out.

Float literals are ``np.float32`` constants: a Python float would promote the maths to float64.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ftgspp.render.contract import ALPHA_MIN, FAR_PLANE, PIXEL_OFFSET, RADIUS_EXTEND
from ftgspp.render.sh import C0, C1, C2, C3
from ftgspp.runtime.jit import JIT

F0 = np.float32(0.0)
F1 = np.float32(1.0)
F2 = np.float32(2.0)
F3 = np.float32(3.0)
F4 = np.float32(4.0)
F_HALF = np.float32(0.5)
F_EPS_DIR = np.float32(1e-8)  # view.py: dirs / norm.clamp_min(1e-8)
F_EPS_SH = np.float32(1e-12)  # sh.py: dirs / norm.clamp_min(1e-12)
F_RADIUS_MAX = np.float32(1.0e6)
F_ALPHA_MIN = np.float32(ALPHA_MIN)
F_EXTEND = np.float32(RADIUS_EXTEND)
F_FAR = np.float32(FAR_PLANE)
F_OFFSET = np.float32(PIXEL_OFFSET)
F_2_63 = np.float32(2.0**63)  # int64's range, as float32
SC0 = np.float32(C0)
SC1 = np.float32(C1)
SC2 = np.array(C2, np.float32)
SC3 = np.array(C3, np.float32)

# Columns of the camera row passed to the kernels (float32 [N_CAM]).
CAM_FX, CAM_FY, CAM_CX, CAM_CY, CAM_W, CAM_H, CAM_NEAR, CAM_EPS2D = 0, 1, 2, 3, 4, 5, 6, 7
CAM_LOX, CAM_HIX, CAM_LOY, CAM_HIY = 8, 9, 10, 11  # clamp limits of x/z and y/z
N_CAM = 12


BLOCK = 256  # Gaussians per parallel work item

# The rows of a block's scratch array (float32 [rows, m]: one row per quantity, one column per
# Gaussian of the block). A method's kernel fills the first ten in both passes (``gaussian_row``)
# and, in the forward pass, the eleventh (``opacity_row``); the rest are the block functions' own.
ROW_LOG_RATIO = 10  # forward: log(opacity / ALPHA_MIN), the opacity-aware radius
FORWARD_ROWS = 16  # + means2d (2) and conics (3)
ROW_GMX, ROW_GMY, ROW_GMZ = 25, 26, 27  # backward: the cotangent of the centre at time t
BACKWARD_ROWS = 28


@njit(**JIT)
def sigmoid(x):
    """1 / (1 + exp(-x)) of a float32 scalar, in float32."""
    return F1 / (F1 + math.exp(-x))


@njit(**JIT)
def _basis(degree, x, y, z, out):
    """Real SH basis (sh.py's order and constants) at the unit direction (x, y, z) into out."""
    out[0] = SC0
    if degree >= 1:
        out[1] = -SC1 * y
        out[2] = SC1 * z
        out[3] = -SC1 * x
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out[4] = SC2[0] * x * y
        out[5] = SC2[1] * y * z
        out[6] = SC2[2] * (F2 * zz - xx - yy)
        out[7] = SC2[3] * x * z
        out[8] = SC2[4] * (xx - yy)
    if degree >= 3:
        xx, yy, zz = x * x, y * y, z * z
        out[9] = SC3[0] * y * (F3 * xx - yy)
        out[10] = SC3[1] * x * y * z
        out[11] = SC3[2] * y * (F4 * zz - xx - yy)
        out[12] = SC3[3] * z * (F2 * zz - F3 * xx - F3 * yy)
        out[13] = SC3[4] * x * (F4 * zz - xx - yy)
        out[14] = SC3[5] * z * (xx - yy)
        out[15] = SC3[6] * x * (xx - F3 * yy)


@njit(**JIT)
def _basis_grad(degree, x, y, z, gb):
    """Gradient of sum_k gb[k] Y_k(x, y, z) with respect to (x, y, z)."""
    gx = F0
    gy = F0
    gz = F0
    if degree >= 1:
        gx += -SC1 * gb[3]
        gy += -SC1 * gb[1]
        gz += SC1 * gb[2]
    if degree >= 2:
        gx += SC2[0] * y * gb[4] + SC2[2] * (-F2 * x) * gb[6] + SC2[3] * z * gb[7] + SC2[4] * (F2 * x) * gb[8]
        gy += SC2[0] * x * gb[4] + SC2[1] * z * gb[5] + SC2[2] * (-F2 * y) * gb[6] - SC2[4] * (F2 * y) * gb[8]
        gz += SC2[1] * y * gb[5] + SC2[2] * (F4 * z) * gb[6] + SC2[3] * x * gb[7]
    if degree >= 3:
        xx, yy, zz = x * x, y * y, z * z
        f6 = np.float32(6.0)
        f8 = np.float32(8.0)
        gx += (
            SC3[0] * y * f6 * x * gb[9] + SC3[1] * y * z * gb[10] + SC3[2] * y * (-F2 * x) * gb[11]
            + SC3[3] * z * (-f6 * x) * gb[12] + SC3[4] * (F4 * zz - F3 * xx - yy) * gb[13]
            + SC3[5] * z * F2 * x * gb[14] + SC3[6] * (F3 * xx - F3 * yy) * gb[15]
        )  # fmt: skip
        gy += (
            SC3[0] * (F3 * xx - F3 * yy) * gb[9] + SC3[1] * x * z * gb[10]
            + SC3[2] * (F4 * zz - xx - F3 * yy) * gb[11] + SC3[3] * z * (-f6 * y) * gb[12]
            + SC3[4] * x * (-F2 * y) * gb[13] + SC3[5] * z * (-F2 * y) * gb[14] + SC3[6] * x * (-f6 * y) * gb[15]
        )  # fmt: skip
        gz += (
            SC3[1] * x * y * gb[10] + SC3[2] * y * f8 * z * gb[11]
            + SC3[3] * (f6 * zz - F3 * xx - F3 * yy) * gb[12] + SC3[4] * x * f8 * z * gb[13]
            + SC3[5] * (xx - yy) * gb[14]
        )  # fmt: skip
    return gx, gy, gz


@njit(**JIT)
def _normalise(x, y, z, eps):
    """(x, y, z) / max(|(x, y, z)|, eps) and that denominator."""
    n = max(np.float32(math.sqrt(x * x + y * y + z * z)), eps)
    return x / n, y / n, z / n, n


@njit(**JIT)
def _normalise_grad(ux, uy, uz, n, eps, gx, gy, gz):
    """Backward of u = v / max(|v|, eps) at v = n u: the cotangent of v."""
    if n > eps:
        dot = ux * gx + uy * gy + uz * gz
        return (gx - ux * dot) / n, (gy - uy * dot) / n, (gz - uz * dot) / n
    return gx / n, gy / n, gz / n


@njit(inline="always", **JIT)
def _rotation(qw, qx, qy, qz):
    """Rotation matrix of the normalised quaternion (project.py's formula), row-major 9-tuple."""
    return (
        F1 - F2 * (qy * qy + qz * qz), F2 * (qx * qy - qw * qz), F2 * (qx * qz + qw * qy),
        F2 * (qx * qy + qw * qz), F1 - F2 * (qx * qx + qz * qz), F2 * (qy * qz - qw * qx),
        F2 * (qx * qz - qw * qy), F2 * (qy * qz + qw * qx), F1 - F2 * (qx * qx + qy * qy),
    )  # fmt: skip


# _dot3 and _sym_dot are left to LLVM's inliner, not Numba's (inline="always"): Numba inlines
# by copying the callee's IR at every call site, and these two are called nine times from each
# _mul3, itself inlined many times: that took the compile of a method's fused backward that
# uses these blocks from about 20 s to 56-62 s (znver4). Left to LLVM: the same bits
# (harness/tracking/same_bits.yaml), the forward as fast, the backward stage 1.09x as long
# (benchmarks/prepare_ab.py; under 1 % of an iteration; BENCHMARKS.md).
@njit(**JIT)
def _dot3(A, B, r, c, a_t, b_t):
    """Entry (r, c) of op(A) op(B) for row-major 3x3 9-tuples, op = transpose where a_t / b_t.

    Summed from +0 in k order, as the earlier array version did, so that results keep their
    bits (the +0 start turns a first product of -0 into +0)."""
    acc = F0
    for k in range(3):
        acc += A[3 * k + r if a_t else 3 * r + k] * B[3 * c + k if b_t else 3 * k + c]
    return acc


@njit(inline="always", **JIT)
def _mul3(A, B, a_t, b_t):
    """op(A) op(B) of row-major 3x3 9-tuples as a 9-tuple (entries by ``_dot3``).

    Matrices are tuples of scalars, not small arrays, so that they stay in registers."""
    return (
        _dot3(A, B, 0, 0, a_t, b_t), _dot3(A, B, 0, 1, a_t, b_t), _dot3(A, B, 0, 2, a_t, b_t),
        _dot3(A, B, 1, 0, a_t, b_t), _dot3(A, B, 1, 1, a_t, b_t), _dot3(A, B, 1, 2, a_t, b_t),
        _dot3(A, B, 2, 0, a_t, b_t), _dot3(A, B, 2, 1, a_t, b_t), _dot3(A, B, 2, 2, a_t, b_t),
    )  # fmt: skip


@njit(**JIT)
def _sym_dot(G, M, r, k):
    """Entry (r, k) of (G + G^T) M for row-major 3x3 9-tuples, each (G + G^T) entry added as
    G[r, c] + G[c, r], summed from +0 in c order."""
    acc = F0
    for c in range(3):
        acc += (G[3 * r + c] + G[3 * c + r]) * M[3 * c + k]
    return acc


@njit(inline="always", **JIT)
def _affine(view):
    """(V, W) of a world-to-camera matrix [4, 4]: V its top three rows as a row-major 12-tuple,
    W their rotation block as a row-major 9-tuple."""
    V = (
        view[0, 0], view[0, 1], view[0, 2], view[0, 3], view[1, 0], view[1, 1], view[1, 2], view[1, 3],
        view[2, 0], view[2, 1], view[2, 2], view[2, 3],
    )  # fmt: skip
    return V, (V[0], V[1], V[2], V[4], V[5], V[6], V[8], V[9], V[10])


@njit(inline="always", **JIT)
def _cam_values(cam):
    """(fx, fy, near, eps2d, (lo x/z, hi x/z, lo y/z, hi y/z)) of a camera row."""
    return cam[CAM_FX], cam[CAM_FY], cam[CAM_NEAR], cam[CAM_EPS2D], (cam[CAM_LOX], cam[CAM_HIX], cam[CAM_LOY], cam[CAM_HIY])


@njit(inline="always", **JIT)
def _geometry(mean_x, mean_y, mean_z, scale, q, V, W, fx, fy, near, lims, eps):
    """Camera-space centre, clamped tangents, Jacobian and 2D covariance of one Gaussian.

    ``scale``: exp(log scales) (3-tuple); ``q``: its quaternion (w, x, y, z); ``V``: the
    camera's ``_affine`` rows and ``W`` their rotation block (row-major 9-tuple); ``lims``:
    the clamp limits (lo x/z, hi x/z, lo y/z, hi y/z). Returns (px, py, pz, z_safe, u, v, u_c,
    v_c, a, b, c, qnorm, R, cov_cam, jac): R (rotation of the normalised quaternion) and
    cov_cam as row-major 9-tuples, jac as the non-zero entries (J00, J02, J11, J12) of
    J = [[J00, 0, J02], [0, J11, J12]]. Arithmetic only: the square root is an LLVM intrinsic
    and the conditions compile to selects, so loops that call it can be vectorised.
    """
    px = V[0] * mean_x + V[1] * mean_y + V[2] * mean_z + V[3]
    py = V[4] * mean_x + V[5] * mean_y + V[6] * mean_z + V[7]
    pz = V[8] * mean_x + V[9] * mean_y + V[10] * mean_z + V[11]
    z = pz if pz >= near and pz <= F_FAR else F1
    u = px / z
    v = py / z
    u_c = min(max(u, lims[0]), lims[1])
    v_c = min(max(v, lims[2]), lims[3])
    j00 = fx / z
    j02 = -fx * u_c / z
    j11 = fy / z
    j12 = -fy * v_c / z
    qw, qx, qy, qz = q
    qn = np.float32(math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz))
    R = _rotation(qw / qn, qx / qn, qy / qn, qz / qn)
    s0, s1, s2 = scale
    M = (R[0] * s0, R[1] * s1, R[2] * s2, R[3] * s0, R[4] * s1, R[5] * s2, R[6] * s0, R[7] * s1, R[8] * s2)
    cov3 = _mul3(M, M, False, True)  # (R S)(R S)^T
    cov_cam = _mul3(_mul3(W, cov3, False, False), W, False, True)  # W cov3 W^T
    # t = J cov_cam (J's zeros multiplied as written: 0 * inf is nan)
    t00 = j00 * cov_cam[0] + F0 * cov_cam[3] + j02 * cov_cam[6]
    t01 = j00 * cov_cam[1] + F0 * cov_cam[4] + j02 * cov_cam[7]
    t02 = j00 * cov_cam[2] + F0 * cov_cam[5] + j02 * cov_cam[8]
    t10 = F0 * cov_cam[0] + j11 * cov_cam[3] + j12 * cov_cam[6]
    t11 = F0 * cov_cam[1] + j11 * cov_cam[4] + j12 * cov_cam[7]
    t12 = F0 * cov_cam[2] + j11 * cov_cam[5] + j12 * cov_cam[8]
    c00 = t00 * j00 + t01 * F0 + t02 * j02
    c01 = t00 * F0 + t01 * j11 + t02 * j12
    c10 = t10 * j00 + t11 * F0 + t12 * j02
    c11 = t10 * F0 + t11 * j11 + t12 * j12
    a = c00 + eps
    b = F_HALF * (c01 + c10)
    c = c11 + eps
    return px, py, pz, z, u, v, u_c, v_c, a, b, c, qn, R, cov_cam, (j00, j02, j11, j12)


@njit(inline="always", **JIT)
def gaussian_row(f, b, x, y, z, qw, qx, qy, qz, ls0, ls1, ls2):
    """Entry b of a block's first ten rows (``f``): the Gaussian's centre at time t (x, y, z), its
    quaternion and its scales (exp of the log scales ls0..ls2), float32 scalars."""
    f[0, b], f[1, b], f[2, b] = x, y, z
    f[3, b], f[4, b], f[5, b], f[6, b] = qw, qx, qy, qz
    f[7, b] = np.float32(math.exp(ls0))
    f[8, b] = np.float32(math.exp(ls1))
    f[9, b] = np.float32(math.exp(ls2))


@njit(inline="always", **JIT)
def opacity_row(f, b, o):
    """Entry b of a forward block's ``ROW_LOG_RATIO`` from the Gaussian's opacity o at time t."""
    f[ROW_LOG_RATIO, b] = np.float32(math.log(o / F_ALPHA_MIN))


@njit(inline="always", **JIT)
def block_rows(blk, n, rows):
    """(lo, hi, f): the Gaussians lo..hi-1 of parallel work item ``blk`` of n, and their scratch rows
    ``f`` (float32 [rows, hi - lo], uninitialised: ``FORWARD_ROWS`` or ``BACKWARD_ROWS``)."""
    lo = blk * BLOCK
    hi = min(n, lo + BLOCK)
    return lo, hi, np.empty((rows, hi - lo), np.float32)


@njit(**JIT)
def forward_outputs(n, n_dim):
    """A forward kernel's outputs for n Gaussians with n_dim colour channels, uninitialised (each
    block writes its rows): means2d [n, 2], conics [n, 3], colors [n, n_dim], opacities [n],
    depths [n], radii [n, 2] int32, phi [n], means_t [n, 3]."""
    return (np.empty((n, 2), np.float32), np.empty((n, 3), np.float32), np.empty((n, n_dim), np.float32),
            np.empty(n, np.float32), np.empty(n, np.float32), np.empty((n, 2), np.int32), np.empty(n, np.float32),
            np.empty((n, 3), np.float32))  # fmt: skip


@njit(inline="always", **JIT)
def _ceil(x):
    """``np.float32(math.ceil(x))`` as the earlier code computed it through an int64, without the
    int64 (a library call that keeps a loop from being vectorised): ceil(x) (+0 for -0) where
    int64 holds it; int64's minimum, as x86's conversion gives, for larger values and NaN."""
    return np.ceil(x) + F0 if abs(x) < F_2_63 else -F_2_63


@njit(**JIT)
def _project_block(m, view, cam, mx, my, mz, qw, qx, qy, qz, s0, s1, s2, log_ratio, opac,
                   depths, m2x, m2y, con0, con1, con2, rx, ry):  # fmt: skip
    """The projection of a block of m Gaussians (entries 0..m-1 of each array): depths, means2d
    (m2x, m2y), conics (con0..2) and radii (rx, ry) from the centres at time t (mx, my, mz),
    quaternions, scales (exp(log scales)), log(opacity / ALPHA_MIN) and opacities.

    One 1D array per quantity (structure of arrays), no library calls and no branches (both
    sides computed, one selected), so that LLVM vectorises the loop on AVX2 and AVX-512 alike;
    an [N, k] array read or written at k i + c keeps it scalar on AVX2 (cost model) and,
    without extra runtime checks, on AVX-512. Lanes never reorder the arithmetic (no
    fast-math): every non-NaN result is the scalar loop's (see the module docstring)."""
    width, height, cx, cy = cam[CAM_W], cam[CAM_H], cam[CAM_CX], cam[CAM_CY]
    fx, fy, near, eps, lims = _cam_values(cam)
    V, W = _affine(view)
    for j in range(m):
        i = np.uint64(j)  # unsigned: no negative-index wrap-around in the loop
        px, py, pz, z, u, v, u_c, v_c, ca, cb, cc, qn, R, cov_cam, jac = _geometry(
            mx[i], my[i], mz[i], (s0[i], s1[i], s2[i]), (qw[i], qx[i], qy[i], qz[i]), V, W, fx, fy, near, lims, eps
        )
        depths[i] = pz
        gx = fx * u + cx
        gy = fy * v + cy
        det = ca * cc - cb * cb
        keep = pz >= near and pz <= F_FAR and det > F0 and opac[i] >= F_ALPHA_MIN
        extend = min(F_EXTEND, np.float32(math.sqrt(F2 * log_ratio[i]))) if keep else F0  # alpha = 1/255 there
        rad_x = min(_ceil(extend * np.float32(math.sqrt(max(ca, F0)))), F_RADIUS_MAX)
        rad_y = min(_ceil(extend * np.float32(math.sqrt(max(cc, F0)))), F_RADIUS_MAX)
        ox = gx + F_OFFSET  # gsplat's pixel coordinates
        oy = gy + F_OFFSET
        on_screen = ox + rad_x > F0 and ox - rad_x < width and oy + rad_y > F0 and oy - rad_y < height
        ok = keep and on_screen and (rad_x > F0 or rad_y > F0)
        rx[i] = np.int32(rad_x) if ok else 0
        ry[i] = np.int32(rad_y) if ok else 0
        m2x[i] = gx if ok else F0
        m2y[i] = gy if ok else F0
        con0[i] = cc / det if ok else F0
        con1[i] = -cb / det if ok else F0
        con2[i] = ca / det if ok else F0


@njit(**JIT)
def projection(lo, hi, f, view, cam, opac, depths, means_t, means2d, conics, radii):
    """The forward projection of the block of Gaussians lo..hi-1, whose rows 0..10 of ``f``
    (``FORWARD_ROWS`` x (hi - lo)) and opacities ``opac[lo:hi]`` the method has written: their
    depths, means2d, conics and radii (``_project_block``) and their centres at time t
    (``means_t``), into rows lo..hi-1 of those outputs."""
    mx, my, mz, qw, qx, qy, qz, s0, s1, s2, log_ratio, m2x, m2y, con0, con1, con2 = (
        f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8], f[9], f[10], f[11], f[12], f[13], f[14], f[15]
    )
    rad = np.empty((2, hi - lo), np.int32)
    _project_block(hi - lo, view, cam, mx, my, mz, qw, qx, qy, qz, s0, s1, s2, log_ratio, opac[lo:hi],
                   depths[lo:hi], m2x, m2y, con0, con1, con2, rad[0], rad[1])  # fmt: skip
    for i in range(lo, hi):
        b = i - lo
        means_t[i, 0], means_t[i, 1], means_t[i, 2] = mx[b], my[b], mz[b]
        means2d[i, 0], means2d[i, 1] = m2x[b], m2y[b]
        conics[i, 0], conics[i, 1], conics[i, 2] = con0[b], con1[b], con2[b]
        radii[i, 0], radii[i, 1] = rad[0, b], rad[1, b]


@njit(**JIT)
def sh_colour(lo, hi, f, centre, sh_degree, sh0, shN, colors):
    """The SH colours of degree ``sh_degree`` of the block of Gaussians lo..hi-1 (rows 0..2 of
    ``f``: their centres at time t) along the viewing direction from ``centre``, into rows
    lo..hi-1 of ``colors``. For a method whose colour is SH; one with RGB writes its own."""
    mx, my, mz = f[0], f[1], f[2]
    n_dim = sh0.shape[2]
    basis = np.empty(16, np.float32)
    for i in range(lo, hi):
        b = i - lo
        # colour along the (twice normalised, as view.py then sh.py do) viewing direction
        d1x, d1y, d1z, _ = _normalise(mx[b] - centre[0], my[b] - centre[1], mz[b] - centre[2], F_EPS_DIR)
        dx, dy, dz, _ = _normalise(d1x, d1y, d1z, F_EPS_SH)
        _basis(sh_degree, dx, dy, dz, basis)
        for ch in range(n_dim):
            rgb = basis[0] * sh0[i, 0, ch]
            for k in range(1, (sh_degree + 1) * (sh_degree + 1)):
                rgb += basis[k] * shN[i, k - 1, ch]
            colors[i, ch] = max(rgb + F_HALF, F0)


@njit(inline="always", **JIT)
def _projection_grads(i, V, W, cam, mx, my, mz, qw, qx, qy, qz, s0, s1, s2, radii_x,
                      g_m2x, g_m2y, g_con0, g_con1, g_con2, g_depths):  # fmt: skip
    """The chain rule through the projection of Gaussian i: (gpx, gpy, gpz), the cotangent of
    its camera-space centre (the depth output's included), and the gradients of its log scales
    (3) and quaternion (4). Culled Gaussians (radii_x 0) get zeros and only their depth's
    cotangent: both sides are computed and one selected (no branch, so that the loops that
    call it are vectorised). ``cam`` is the camera row's values as a tuple (``_cam_values``)."""
    fx, fy, near, eps, lims = cam
    q = (qw[i], qx[i], qy[i], qz[i])
    sx, sy, sz = s0[i], s1[i], s2[i]
    px, py, pz, z, u, v, u_c, v_c, ca, cb, cc, qn, R, cov_cam, jac = _geometry(
        mx[i], my[i], mz[i], (sx, sy, sz), q, V, W, fx, fy, near, lims, eps
    )
    # conic = (c, -b, a) / det, det = a c - b^2
    det = ca * cc - cb * cb
    id2 = F1 / (det * det)
    gA, gB, gC = g_con0[i], g_con1[i], g_con2[i]
    ga = (-cc * cc * gA + cb * cc * gB - cb * cb * gC) * id2
    gb = (F2 * cb * cc * gA - (det + F2 * cb * cb) * gB + F2 * ca * cb * gC) * id2
    gc = (-cb * cb * gA + ca * cb * gB - ca * ca * gC) * id2
    # cov2d = J C J^T with a = cov00 + eps, b = (cov01 + cov10) / 2, c = cov11 + eps:
    # G = [[ga, gb/2], [gb/2, gc]], dL/dC = J^T G J, dL/dJ = 2 G J C.
    g00, g01, g11 = ga, F_HALF * gb, gc
    j00, j02, j11, j12 = jac  # J = [[j00, 0, j02], [0, j11, j12]]; its zeros multiplied as written
    gj00, gj01, gj02 = g00 * j00 + g01 * F0, g00 * F0 + g01 * j11, g00 * j02 + g01 * j12  # G J
    gj10, gj11, gj12 = g01 * j00 + g11 * F0, g01 * F0 + g11 * j11, g01 * j02 + g11 * j12
    g_cam = (  # J^T (G J)
        j00 * gj00 + F0 * gj10, j00 * gj01 + F0 * gj11, j00 * gj02 + F0 * gj12,
        F0 * gj00 + j11 * gj10, F0 * gj01 + j11 * gj11, F0 * gj02 + j11 * gj12,
        j02 * gj00 + j12 * gj10, j02 * gj01 + j12 * gj11, j02 * gj02 + j12 * gj12,
    )  # fmt: skip
    # dL/dJ = 2 (G J) C: the entries at J's non-zeros
    gJ00 = F2 * (gj00 * cov_cam[0] + gj01 * cov_cam[3] + gj02 * cov_cam[6])
    gJ02 = F2 * (gj00 * cov_cam[2] + gj01 * cov_cam[5] + gj02 * cov_cam[8])
    gJ11 = F2 * (gj10 * cov_cam[1] + gj11 * cov_cam[4] + gj12 * cov_cam[7])
    gJ12 = F2 * (gj10 * cov_cam[2] + gj11 * cov_cam[5] + gj12 * cov_cam[8])
    # J = [[fx/z, 0, -fx u_c/z], [0, fy/z, -fy v_c/z]]; the depth output's cotangent first
    iz = F1 / z
    gpz = g_depths[i] + (-gJ00 * fx + gJ02 * fx * u_c - gJ11 * fy + gJ12 * fy * v_c) * iz * iz
    gu = g_m2x[i] * fx
    gv_ = g_m2y[i] * fy
    # the clamp passes the gradient inside its range
    gu = gu + -gJ02 * fx * iz if lims[0] <= u <= lims[1] else gu
    gv_ = gv_ + -gJ12 * fy * iz if lims[2] <= v <= lims[3] else gv_
    # u = x / z, v = y / z
    gpx = F0 + gu * iz
    gpy = F0 + gv_ * iz
    gpz += -(gu * u + gv_ * v) * iz
    # cov_cam = W cov3 W^T  ->  dL/dcov3 = W^T g_cam W
    g3 = _mul3(_mul3(W, g_cam, True, False), W, False, False)
    # cov3 = M M^T, M = R S  ->  dL/dM = (g3 + g3^T) M; dR_rk = dM_rk s_k; ds_k = sum_r dM_rk R_rk
    M = (R[0] * sx, R[1] * sy, R[2] * sz, R[3] * sx, R[4] * sy, R[5] * sz, R[6] * sx, R[7] * sy, R[8] * sz)
    gM = (
        _sym_dot(g3, M, 0, 0), _sym_dot(g3, M, 0, 1), _sym_dot(g3, M, 0, 2),
        _sym_dot(g3, M, 1, 0), _sym_dot(g3, M, 1, 1), _sym_dot(g3, M, 1, 2),
        _sym_dot(g3, M, 2, 0), _sym_dot(g3, M, 2, 1), _sym_dot(g3, M, 2, 2),
    )  # fmt: skip
    gR = (gM[0] * sx, gM[1] * sy, gM[2] * sz, gM[3] * sx, gM[4] * sy, gM[5] * sz,
          gM[6] * sx, gM[7] * sy, gM[8] * sz)  # fmt: skip
    nw, nx, ny, nz = q[0] / qn, q[1] / qn, q[2] / qn, q[3] / qn
    gw = F2 * (-nz * gR[1] + ny * gR[2] + nz * gR[3] - nx * gR[5] - ny * gR[6] + nx * gR[7])
    gx = F2 * (ny * gR[1] + nz * gR[2] + ny * gR[3] - F2 * nx * gR[4] - nw * gR[5]
               + nz * gR[6] + nw * gR[7] - F2 * nx * gR[8])  # fmt: skip
    gy = F2 * (-F2 * ny * gR[0] + nx * gR[1] + nw * gR[2] + nx * gR[3] + nz * gR[5]
               - nw * gR[6] + nz * gR[7] - F2 * ny * gR[8])  # fmt: skip
    gz = F2 * (-F2 * nz * gR[0] - nw * gR[1] + nx * gR[2] + nw * gR[3] - F2 * nz * gR[4]
               + ny * gR[5] + nx * gR[6] + ny * gR[7])  # fmt: skip
    dot = nw * gw + nx * gx + ny * gy + nz * gz  # q / |q|
    ok = radii_x[i] > 0
    return (
        gpx if ok else F0,
        gpy if ok else F0,
        gpz if ok else g_depths[i],
        (F0 + gM[0] * R[0] + gM[3] * R[3] + gM[6] * R[6]) * sx if ok else F0,  # s = exp(log s)
        (F0 + gM[1] * R[1] + gM[4] * R[4] + gM[7] * R[7]) * sy if ok else F0,
        (F0 + gM[2] * R[2] + gM[5] * R[5] + gM[8] * R[8]) * sz if ok else F0,
        (gw - nw * dot) / qn if ok else F0,
        (gx - nx * dot) / qn if ok else F0,
        (gy - ny * dot) / qn if ok else F0,
        (gz - nz * dot) / qn if ok else F0,
    )


@njit(**JIT)
def _position_block_backward(m, view, cam, mx, my, mz, qw, qx, qy, qz, s0, s1, s2, radii_x,
                             g_m2x, g_m2y, g_con0, g_con1, g_con2, g_depths, g_mtx, g_mty, g_mtz,
                             g_mx, g_my, g_mz):  # fmt: skip
    """g_m* = g_mt* + what the projection of a block of m Gaussians sends back to their centres
    at time t (``_projection_grads``). One 1D array per quantity, as in ``_project_block``, and
    fewer than eight arrays written: with more, LLVM gives up the runtime overlap checks that
    vectorising needs, so the shape gradients have a loop of their own."""
    c = _cam_values(cam)
    V, W = _affine(view)
    for j in range(m):
        i = np.uint64(j)  # unsigned: no negative-index wrap-around in the loop
        gpx, gpy, gpz, _, _, _, _, _, _, _ = _projection_grads(
            i, V, W, c, mx, my, mz, qw, qx, qy, qz, s0, s1, s2, radii_x, g_m2x, g_m2y, g_con0, g_con1, g_con2, g_depths
        )
        # p = W mean + t
        g_mx[i] = g_mtx[i] + (V[0] * gpx + V[4] * gpy + V[8] * gpz)
        g_my[i] = g_mty[i] + (V[1] * gpx + V[5] * gpy + V[9] * gpz)
        g_mz[i] = g_mtz[i] + (V[2] * gpx + V[6] * gpy + V[10] * gpz)


@njit(**JIT)
def _shape_block_backward(m, view, cam, mx, my, mz, qw, qx, qy, qz, s0, s1, s2, radii_x,
                          g_m2x, g_m2y, g_con0, g_con1, g_con2, g_depths,
                          gr_ls0, gr_ls1, gr_ls2, gr_qw, gr_qx, gr_qy, gr_qz):  # fmt: skip
    """The gradients of the log scales and quaternions of a block of m Gaussians
    (``_projection_grads``; see ``_position_block_backward``)."""
    c = _cam_values(cam)
    V, W = _affine(view)
    for j in range(m):
        i = np.uint64(j)
        _, _, _, gr_ls0[i], gr_ls1[i], gr_ls2[i], gr_qw[i], gr_qx[i], gr_qy[i], gr_qz[i] = _projection_grads(
            i, V, W, c, mx, my, mz, qw, qx, qy, qz, s0, s1, s2, radii_x, g_m2x, g_m2y, g_con0, g_con1, g_con2, g_depths
        )


@njit(**JIT)
def projection_backward(lo, hi, f, view, cam, radii, g_means2d, g_conics, g_depths, g_means_t, gr_ls, gr_quats):
    """The backward projection of the block of Gaussians lo..hi-1, whose rows 0..9 of ``f``
    (``BACKWARD_ROWS`` x (hi - lo)) the method has written as in the forward pass: the gradients
    of their log scales and quaternions (rows lo..hi-1 of ``gr_ls``, ``gr_quats``), and in rows
    ``ROW_GMX`` .. ``ROW_GMZ`` the cotangent of each centre at time t: the ``means_t`` output's
    (``g_means_t``) and the projection's (``sh_colour_backward`` adds the colour's). ``radii``
    and the cotangents are the whole forward outputs' arrays."""
    mx, my, mz, qw, qx, qy, qz, s0, s1, s2, g_m2x, g_m2y, g_con0, g_con1, g_con2, g_mtx, g_mty, g_mtz = (
        f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8], f[9], f[10], f[11], f[12], f[13], f[14], f[15],
        f[16], f[17],
    )  # fmt: skip
    gr_ls0, gr_ls1, gr_ls2, gr_qw, gr_qx, gr_qy, gr_qz, g_mx, g_my, g_mz = (
        f[18], f[19], f[20], f[21], f[22], f[23], f[24], f[25], f[26], f[27]
    )
    radii_x = np.empty(hi - lo, np.int32)
    for i in range(lo, hi):  # the cotangents' rows
        b = i - lo
        radii_x[b] = radii[i, 0]
        g_m2x[b], g_m2y[b] = g_means2d[i, 0], g_means2d[i, 1]
        g_con0[b], g_con1[b], g_con2[b] = g_conics[i, 0], g_conics[i, 1], g_conics[i, 2]
        g_mtx[b], g_mty[b], g_mtz[b] = g_means_t[i, 0], g_means_t[i, 1], g_means_t[i, 2]
    g_dep = g_depths[lo:hi]
    _position_block_backward(
        hi - lo, view, cam, mx, my, mz, qw, qx, qy, qz, s0, s1, s2, radii_x, g_m2x, g_m2y, g_con0, g_con1, g_con2,
        g_dep, g_mtx, g_mty, g_mtz, g_mx, g_my, g_mz,
    )  # fmt: skip
    _shape_block_backward(
        hi - lo, view, cam, mx, my, mz, qw, qx, qy, qz, s0, s1, s2, radii_x, g_m2x, g_m2y, g_con0, g_con1, g_con2,
        g_dep, gr_ls0, gr_ls1, gr_ls2, gr_qw, gr_qx, gr_qy, gr_qz,
    )  # fmt: skip
    for i in range(lo, hi):
        b = i - lo
        gr_ls[i, 0], gr_ls[i, 1], gr_ls[i, 2] = gr_ls0[b], gr_ls1[b], gr_ls2[b]
        gr_quats[i, 0], gr_quats[i, 1], gr_quats[i, 2], gr_quats[i, 3] = gr_qw[b], gr_qx[b], gr_qy[b], gr_qz[b]


@njit(**JIT)
def sh_colour_backward(lo, hi, f, centre, sh_degree, sh0, shN, g_colors, gr_sh0, gr_shN):
    """The backward of ``sh_colour`` for the block of Gaussians lo..hi-1 (after
    ``projection_backward``): the gradients of their SH coefficients (rows lo..hi-1 of
    ``gr_sh0``, ``gr_shN``), and the colour's share of the cotangent of each centre at time t
    added to rows ``ROW_GMX`` .. ``ROW_GMZ`` of ``f``."""
    mx, my, mz, g_mx, g_my, g_mz = f[0], f[1], f[2], f[ROW_GMX], f[ROW_GMY], f[ROW_GMZ]
    n_dim = sh0.shape[2]
    n_bases = (sh_degree + 1) * (sh_degree + 1)
    basis = np.empty(16, np.float32)
    g_basis = np.empty(16, np.float32)
    for i in range(lo, hi):
        b = i - lo
        for k in range(16):
            g_basis[k] = F0
        d1x, d1y, d1z, n1 = _normalise(mx[b] - centre[0], my[b] - centre[1], mz[b] - centre[2], F_EPS_DIR)
        dx, dy, dz, n2 = _normalise(d1x, d1y, d1z, F_EPS_SH)
        _basis(sh_degree, dx, dy, dz, basis)
        for ch in range(n_dim):
            rgb = basis[0] * sh0[i, 0, ch]
            for k in range(1, n_bases):
                rgb += basis[k] * shN[i, k - 1, ch]
            g_rgb = g_colors[i, ch] if rgb + F_HALF >= F0 else F0  # clamp_min passes at >= 0
            gr_sh0[i, 0, ch] = basis[0] * g_rgb
            for k in range(1, n_bases):
                gr_shN[i, k - 1, ch] = basis[k] * g_rgb
                g_basis[k] += shN[i, k - 1, ch] * g_rgb
        if sh_degree >= 1:
            gdx, gdy, gdz = _basis_grad(sh_degree, dx, dy, dz, g_basis)
            gdx, gdy, gdz = _normalise_grad(dx, dy, dz, n2, F_EPS_SH, gdx, gdy, gdz)
            gdx, gdy, gdz = _normalise_grad(d1x, d1y, d1z, n1, F_EPS_DIR, gdx, gdy, gdz)
            g_mx[b] += gdx
            g_my[b] += gdy
            g_mz[b] += gdz
