"""FreeTimeGS's fused stage on the ``cpu`` backend: its time evaluation in Numba, then the shared
SH colour and EWA projection (``ftgspp.render.prepare_kernels``), as one autograd node.

``prepare`` replaces ``FreeTimeGaussians.at_time``, ``sh.eval_sh`` and ``project.project``
(dozens of small PyTorch operations and their autograd bookkeeping) with one Numba forward
kernel and one hand-written backward kernel; outputs agree with that PyTorch path to float32
rounding and gradients reach every parameter (``tests/methods/test_freetime_fused.py``). What is
FreeTimeGS's here is the time evaluation and its chain rule:

    mean(t) = mu + v (t - mu_t),  phi = g + (1 - g) a  or  a,  a = exp(-0.5 ((t - mu_t) / s)^2)
    opacity = sigmoid(o) phi,     s = max_duration / 6 sigmoid(d)  or  exp(d)

    from ftgspp.methods.freetime_fused import prepare
    p = prepare(model.params, t, CameraTensors(viewmat, K, centre, W, H), sh_degree, None, False, 20.0)
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
    BACKWARD_ROWS, BLOCK, F0, F1, F_HALF, FORWARD_ROWS, ROW_GMX, ROW_GMY, ROW_GMZ, block_rows, forward_outputs,
    gaussian_row, opacity_row, projection, projection_backward, sh_colour, sh_colour_backward, sigmoid,
)  # fmt: skip
from ftgspp.runtime.jit import JIT

# The model parameters the kernels read, in kernel argument order.
PARAM_NAMES = ("means", "velocities", "times", "durations", "scales", "quats", "opacities", "gates", "sh0", "shN")


@njit(**JIT)
def _temporal(t, mu_t, d, gate_logit, max_duration, gate_on, gate_gamma):
    """(dt, s, a, gate value, phi) at time t of a Gaussian with centre mu_t, duration
    parameter d and gate logit (float32 scalars, so that calls carry no arrays)."""
    if max_duration > F0:
        s = max_duration * sigmoid(d)  # max_duration holds max_duration / 6
    else:
        s = np.float32(math.exp(d))
    dt = t - mu_t
    r = dt / s
    a = np.float32(math.exp(np.float32(-F_HALF) * (r * r)))
    gv = F0
    phi = a
    if gate_on:
        gv = sigmoid(gate_gamma * gate_logit)
        phi = gv + (F1 - gv) * a
    return dt, s, a, gv, phi


@njit(parallel=True, **JIT)
def prepare_forward(
    means: np.ndarray,  # [N, 3] float32
    velocities: np.ndarray,  # [N, 3]
    times: np.ndarray,  # [N]
    durations: np.ndarray,  # [N]
    log_scales: np.ndarray,  # [N, 3]
    quats: np.ndarray,  # [N, 4]
    opacity_logits: np.ndarray,  # [N]
    gate_logits: np.ndarray,  # [N]
    sh0: np.ndarray,  # [N, 1, D]
    shN: np.ndarray,  # [N, K - 1, D]
    view: np.ndarray,  # [4, 4] world-to-camera
    centre: np.ndarray,  # [3] camera centre (world)
    cam: np.ndarray,  # [N_CAM] camera row (prepare_kernels.CAM_*)
    t: np.float32,
    sh_degree: int,
    max_duration: np.float32,  # max_duration / 6, or <= 0 for s = exp(d)
    gate_on: bool,
    gate_gamma: np.float32,
):
    """Forward pass: (means2d [N, 2], conics [N, 3], colors [N, D], opacities [N], depths [N],
    radii [N, 2] int32, phi [N], means_t [N, 3]), all float32 but radii."""
    n = means.shape[0]
    n_dim = sh0.shape[2]
    means2d, conics, colors, opac, depths, radii, phis, means_t = forward_outputs(n, n_dim)
    for blk in prange((n + BLOCK - 1) // BLOCK):
        lo, hi, f = block_rows(blk, n, FORWARD_ROWS)  # the block's Gaussians and rows (prepare_kernels)
        for i in range(lo, hi):  # the library calls (exp, log), one Gaussian at a time
            dt, s, a, gv, phi = _temporal(
                t, times[i], durations[i], gate_logits[i], max_duration, gate_on, gate_gamma
            )
            phis[i] = phi
            o = sigmoid(opacity_logits[i]) * phi
            opac[i] = o
            opacity_row(f, i - lo, o)
            gaussian_row(
                f, i - lo, means[i, 0] + velocities[i, 0] * dt, means[i, 1] + velocities[i, 1] * dt,
                means[i, 2] + velocities[i, 2] * dt, quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3],
                log_scales[i, 0], log_scales[i, 1], log_scales[i, 2],
            )  # fmt: skip
        projection(lo, hi, f, view, cam, opac, depths, means_t, means2d, conics, radii)
        sh_colour(lo, hi, f, centre, sh_degree, sh0, shN, colors)
    return means2d, conics, colors, opac, depths, radii, phis, means_t


@njit(parallel=True, **JIT)
def prepare_backward(
    means: np.ndarray,
    velocities: np.ndarray,
    times: np.ndarray,
    durations: np.ndarray,
    log_scales: np.ndarray,
    quats: np.ndarray,
    opacity_logits: np.ndarray,
    gate_logits: np.ndarray,
    sh0: np.ndarray,
    shN: np.ndarray,
    view: np.ndarray,
    centre: np.ndarray,
    cam: np.ndarray,
    t: np.float32,
    sh_degree: int,
    max_duration: np.float32,
    gate_on: bool,
    gate_gamma: np.float32,
    radii: np.ndarray,  # [N, 2] int32 from the forward pass
    g_means2d: np.ndarray,  # [N, 2] cotangents of the forward outputs
    g_conics: np.ndarray,  # [N, 3]
    g_colors: np.ndarray,  # [N, D]
    g_opac: np.ndarray,  # [N]
    g_depths: np.ndarray,  # [N]
    g_phi: np.ndarray,  # [N]
    g_means_t: np.ndarray,  # [N, 3]
):
    """Gradients of the inputs (same order as ``prepare_forward``'s array arguments, float32):
    means, velocities, times, durations, log_scales, quats, opacity_logits, gate_logits, sh0, shN."""
    n = means.shape[0]
    gr_means = np.empty((n, 3), np.float32)
    gr_vel = np.empty((n, 3), np.float32)
    gr_times = np.empty(n, np.float32)
    gr_dur = np.empty(n, np.float32)
    gr_ls = np.empty((n, 3), np.float32)
    gr_quats = np.empty((n, 4), np.float32)
    gr_o = np.empty(n, np.float32)
    gr_gate = np.zeros(n, np.float32)
    gr_sh0 = np.empty(sh0.shape, np.float32)
    gr_shN = np.zeros(shN.shape, np.float32)
    for blk in prange((n + BLOCK - 1) // BLOCK):
        lo, hi, f = block_rows(blk, n, BACKWARD_ROWS)  # the block's Gaussians and rows (prepare_kernels)
        temporal = np.empty((5, hi - lo), np.float32)  # the forward's (dt, s, a, gate value, phi)
        for i in range(lo, hi):  # the library calls (exp), one Gaussian at a time
            b = i - lo
            dt, s, a, gv, phi = _temporal(
                t, times[i], durations[i], gate_logits[i], max_duration, gate_on, gate_gamma
            )
            temporal[0, b], temporal[1, b], temporal[2, b], temporal[3, b], temporal[4, b] = dt, s, a, gv, phi
            gaussian_row(
                f, b, means[i, 0] + velocities[i, 0] * dt, means[i, 1] + velocities[i, 1] * dt,
                means[i, 2] + velocities[i, 2] * dt, quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3],
                log_scales[i, 0], log_scales[i, 1], log_scales[i, 2],
            )  # fmt: skip
        projection_backward(lo, hi, f, view, cam, radii, g_means2d, g_conics, g_depths, g_means_t, gr_ls, gr_quats)
        sh_colour_backward(lo, hi, f, centre, sh_degree, sh0, shN, g_colors, gr_sh0, gr_shN)
        for i in range(lo, hi):
            b = i - lo
            dt, s, a, gv, phi = temporal[0, b], temporal[1, b], temporal[2, b], temporal[3, b], temporal[4, b]
            gmx = f[ROW_GMX, b]  # the cotangent of the centre at time t
            gmy = f[ROW_GMY, b]
            gmz = f[ROW_GMZ, b]
            # --- time: mean_t = mu + v dt, dt = t - mu_t; opacity = sigmoid(o) phi
            gr_means[i, 0] = gmx
            gr_means[i, 1] = gmy
            gr_means[i, 2] = gmz
            gr_vel[i, 0] = gmx * dt
            gr_vel[i, 1] = gmy * dt
            gr_vel[i, 2] = gmz * dt
            g_dt = gmx * velocities[i, 0] + gmy * velocities[i, 1] + gmz * velocities[i, 2]
            sig_o = sigmoid(opacity_logits[i])
            g_phi_total = g_phi[i] + g_opac[i] * sig_o
            gr_o[i] = g_opac[i] * phi * sig_o * (F1 - sig_o)
            g_a = g_phi_total
            if gate_on:  # phi = g + (1 - g) a, g = sigmoid(gamma logit)
                g_a = g_phi_total * (F1 - gv)
                gr_gate[i] = g_phi_total * (F1 - a) * gate_gamma * gv * (F1 - gv)
            # a = exp(-r^2 / 2), r = dt / s
            r = dt / s
            g_r = -g_a * a * r
            g_dt += g_r / s
            g_s = -g_r * r / s
            gr_times[i] = -g_dt
            if max_duration > F0:  # s = (max/6) sigmoid(d): ds/dd = s (1 - sigmoid(d))
                gr_dur[i] = g_s * s * (F1 - sigmoid(durations[i]))
            else:  # s = exp(d)
                gr_dur[i] = g_s * s
    return gr_means, gr_vel, gr_times, gr_dur, gr_ls, gr_quats, gr_o, gr_gate, gr_sh0, gr_shN


KERNELS = FusedKernels(prepare_forward, prepare_backward)


def prepare(
    params: Mapping[str, Tensor],  # the model's parameters (PARAM_NAMES), float32 on the CPU
    t: float,  # seconds
    camera: CameraTensors,
    sh_degree: int,
    max_duration: float | None,  # None: s = exp(d)
    gate: bool,
    gate_gamma: float,
    near_plane: float = 0.01,
    eps2d: float = EPS2D,
) -> Prepared:
    """Evaluate, colour and project every Gaussian at time ``t`` (see the module docstring)."""
    n_bases = (sh_degree + 1) ** 2
    if not 0 <= sh_degree <= 3:
        raise ValueError(f"SH degree must be in [0, 3], got {sh_degree}")
    if params["shN"].shape[1] + 1 < n_bases:
        raise ValueError(f"degree {sh_degree} needs {n_bases} SH coefficients, got {params['shN'].shape[1] + 1}")
    if max_duration is not None and not max_duration > 0:
        raise ValueError(f"max_duration must be positive or None, got {max_duration}")
    settings = (
        np.float32(t), int(sh_degree), np.float32(0.0 if max_duration is None else max_duration / 6.0),
        bool(gate), np.float32(gate_gamma),
    )  # fmt: skip
    # without the gate its logits take no part at all (as in at_time): no gradient
    no_grad = frozenset() if gate else frozenset({PARAM_NAMES.index("gates")})
    return fused_prepare(KERNELS, [params[k] for k in PARAM_NAMES], settings, camera, no_grad, near_plane, eps2d)
