"""Spacetime Gaussians' fused stage on the ``cpu`` backend: its time evaluation in Numba, then the
shared EWA projection (``ftgspp.render.prepare_kernels``), as one autograd node.

``prepare`` replaces ``SpacetimeGaussians.at_time`` and ``project.project`` (dozens of small
PyTorch operations and their autograd bookkeeping) with one Numba forward kernel and one
hand-written backward kernel; outputs agree with that PyTorch path to float32 rounding and
gradients reach every parameter (``tests/methods/test_stg_fused.py``). What is STGS's here is
the time evaluation and its chain rule, with Δt = t − μτ:

    mean(t) = μ + b1 Δt + b2 Δt² + b3 Δt³,   quat(t) = q + ω Δt   (normalised by the projection)
    opacity = sigmoid(o) φ,                  φ = exp(−(Δt / exp(s̃))²)
    colour  = c, the RGB as given (no SH, no clamp)

    from ftgspp.methods.stg_fused import prepare
    p = prepare(model.params, t, CameraTensors(viewmat, K, centre, W, H))
    image, alpha, depth = cpu.rasterize(p.means2d, p.conics, p.colors, p.opacities, p.depths, p.radii, W, H)

Backward results are bitwise identical across runs and Numba thread counts (no reductions
across Gaussians). Float literals are ``np.float32`` constants: a Python float would promote
the maths to float64.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np
from numba import njit, prange
from torch import Tensor

from ftgspp.render.contract import EPS2D, CameraTensors
from ftgspp.render.prepare import FusedKernels, Prepared, fused_prepare
from ftgspp.render.prepare_kernels import (
    BACKWARD_ROWS, BLOCK, F0, F1, F2, F3, FORWARD_ROWS, ROW_GMX, ROW_GMY, ROW_GMZ, block_rows, forward_outputs,
    gaussian_row, opacity_row, projection, projection_backward, sigmoid,
)  # fmt: skip
from ftgspp.runtime.jit import JIT

# The model parameters the kernels read, in kernel argument order.
PARAM_NAMES = ("means", "trbf_center", "trbf_scale", "motion", "quats", "omega", "scales", "opacities", "rgb")


@njit(**JIT)
def _temporal(t, centre, log_scale):
    """(Δt, s, r, φ) at time t of a Gaussian with temporal centre μτ and log temporal scale s̃
    (float32 scalars): Δt = t − μτ, s = exp(s̃), r = Δt / s, φ = exp(−r²), as ``at_time``
    computes them."""
    dt = t - centre
    s = np.float32(math.exp(log_scale))
    r = dt / s
    return dt, s, r, np.float32(math.exp(-(r * r)))


@njit(inline="always", **JIT)
def _state_row(f, b, i, dt, means, motion, quats, omega, log_scales):
    """Gaussian i's centre and quaternion at Δt and its scales into entry b of the block's rows."""
    dt2 = dt * dt
    dt3 = dt2 * dt  # at_time's dt**3 is (dt dt) dt
    gaussian_row(
        f, b,
        means[i, 0] + motion[i, 0] * dt + motion[i, 3] * dt2 + motion[i, 6] * dt3,
        means[i, 1] + motion[i, 1] * dt + motion[i, 4] * dt2 + motion[i, 7] * dt3,
        means[i, 2] + motion[i, 2] * dt + motion[i, 5] * dt2 + motion[i, 8] * dt3,
        quats[i, 0] + omega[i, 0] * dt, quats[i, 1] + omega[i, 1] * dt, quats[i, 2] + omega[i, 2] * dt,
        quats[i, 3] + omega[i, 3] * dt, log_scales[i, 0], log_scales[i, 1], log_scales[i, 2],
    )  # fmt: skip


@njit(parallel=True, **JIT)
def prepare_forward(
    means: np.ndarray,  # [N, 3] float32
    trbf_center: np.ndarray,  # [N]
    trbf_scale: np.ndarray,  # [N]
    motion: np.ndarray,  # [N, 9] b1 | b2 | b3
    quats: np.ndarray,  # [N, 4]
    omega: np.ndarray,  # [N, 4]
    log_scales: np.ndarray,  # [N, 3]
    opacity_logits: np.ndarray,  # [N]
    rgb: np.ndarray,  # [N, D]
    view: np.ndarray,  # [4, 4] world-to-camera
    centre: np.ndarray,  # [3] camera centre (world), unused: the colour is view-independent
    cam: np.ndarray,  # [N_CAM] camera row (prepare_kernels.CAM_*)
    t: np.float32,
):
    """Forward pass: the outputs of ``prepare_kernels.forward_outputs``, colours the RGB as given."""
    n = means.shape[0]
    n_dim = rgb.shape[1]
    means2d, conics, colors, opac, depths, radii, phis, means_t = forward_outputs(n, n_dim)
    for blk in prange((n + BLOCK - 1) // BLOCK):
        lo, hi, f = block_rows(blk, n, FORWARD_ROWS)  # the block's Gaussians and rows (prepare_kernels)
        for i in range(lo, hi):  # the library calls (exp, log), one Gaussian at a time
            dt, s, r, phi = _temporal(t, trbf_center[i], trbf_scale[i])
            phis[i] = phi
            o = sigmoid(opacity_logits[i]) * phi
            opac[i] = o
            opacity_row(f, i - lo, o)
            _state_row(f, i - lo, i, dt, means, motion, quats, omega, log_scales)
            for ch in range(n_dim):
                colors[i, ch] = rgb[i, ch]
        projection(lo, hi, f, view, cam, opac, depths, means_t, means2d, conics, radii)
    return means2d, conics, colors, opac, depths, radii, phis, means_t


@njit(parallel=True, **JIT)
def prepare_backward(
    means, trbf_center, trbf_scale, motion, quats, omega, log_scales, opacity_logits, rgb, view, centre, cam, t,
    # prepare_forward's arguments, the forward pass's radii, the cotangents of its other outputs (render.prepare)
    radii, g_means2d, g_conics, g_colors, g_opac, g_depths, g_phi, g_means_t,
):
    """Gradients of the inputs (same order as ``prepare_forward``'s array arguments, float32):
    means, trbf_center, trbf_scale, motion, quats, omega, log_scales, opacity_logits, rgb."""
    n = means.shape[0]
    n_dim = rgb.shape[1]
    gr_means = np.empty((n, 3), np.float32)
    gr_centre = np.empty(n, np.float32)
    gr_tscale = np.empty(n, np.float32)
    gr_motion = np.empty((n, 9), np.float32)
    gr_quats = np.empty((n, 4), np.float32)  # the projection's: the cotangent of quat(t)
    gr_omega = np.empty((n, 4), np.float32)
    gr_ls = np.empty((n, 3), np.float32)
    gr_o = np.empty(n, np.float32)
    gr_rgb = np.empty((n, n_dim), np.float32)
    for blk in prange((n + BLOCK - 1) // BLOCK):
        lo, hi, f = block_rows(blk, n, BACKWARD_ROWS)  # the block's Gaussians and rows (prepare_kernels)
        temporal = np.empty((4, hi - lo), np.float32)  # the forward's (dt, s, r, phi)
        for i in range(lo, hi):  # the library calls (exp), one Gaussian at a time
            b = i - lo
            dt, s, r, phi = _temporal(t, trbf_center[i], trbf_scale[i])
            temporal[0, b], temporal[1, b], temporal[2, b], temporal[3, b] = dt, s, r, phi
            _state_row(f, b, i, dt, means, motion, quats, omega, log_scales)
        projection_backward(lo, hi, f, view, cam, radii, g_means2d, g_conics, g_depths, g_means_t, gr_ls, gr_quats)
        for i in range(lo, hi):
            b = i - lo
            dt, s, r, phi = temporal[0, b], temporal[1, b], temporal[2, b], temporal[3, b]
            dt2 = dt * dt
            g_mt = (f[ROW_GMX, b], f[ROW_GMY, b], f[ROW_GMZ, b])  # the cotangent of the centre at time t
            # --- mean(t) = mu + b1 dt + b2 dt^2 + b3 dt^3: d/dmu = 1, d/db_k = dt^k, d/ddt = b1 + 2 b2 dt + 3 b3 dt^2
            g_dt = F0
            for c in range(3):
                gr_means[i, c] = g_mt[c]
                gr_motion[i, c] = g_mt[c] * dt
                gr_motion[i, 3 + c] = g_mt[c] * dt2
                gr_motion[i, 6 + c] = g_mt[c] * (dt2 * dt)
                g_dt += g_mt[c] * (motion[i, c] + F2 * motion[i, 3 + c] * dt + F3 * motion[i, 6 + c] * dt2)
            # --- quat(t) = q + omega dt: d/dq = 1 (gr_quats as it is), d/domega = dt, d/ddt = omega
            for c in range(4):
                gr_omega[i, c] = gr_quats[i, c] * dt
                g_dt += gr_quats[i, c] * omega[i, c]
            # --- opacity = sigmoid(o) phi; phi = exp(-r^2), r = dt / s, s = exp(log s)
            sig_o = sigmoid(opacity_logits[i])
            g_phi_total = g_phi[i] + g_opac[i] * sig_o
            gr_o[i] = g_opac[i] * phi * sig_o * (F1 - sig_o)
            g_r = -F2 * r * phi * g_phi_total
            g_dt += g_r / s
            gr_tscale[i] = -g_r * r  # d r / d log s = -r
            gr_centre[i] = -g_dt  # dt = t - mu_tau
            for ch in range(n_dim):  # colour = rgb
                gr_rgb[i, ch] = g_colors[i, ch]
    return gr_means, gr_centre, gr_tscale, gr_motion, gr_quats, gr_omega, gr_ls, gr_o, gr_rgb


KERNELS = FusedKernels(prepare_forward, prepare_backward)


def prepare(
    params: Mapping[str, Tensor],  # the model's parameters (PARAM_NAMES), float32 on the CPU
    t: float,  # seconds
    camera: CameraTensors,
    near_plane: float = 0.01,
    eps2d: float = EPS2D,
) -> Prepared:
    """Evaluate, colour and project every Gaussian at time ``t`` (see the module docstring)."""
    return fused_prepare(KERNELS, [params[k] for k in PARAM_NAMES], (np.float32(t),), camera, frozenset(),
                         near_plane, eps2d)  # fmt: skip
