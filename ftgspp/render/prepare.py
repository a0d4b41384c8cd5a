"""Fused per-Gaussian stage of the ``cpu`` backend: time evaluation + SH colour + EWA projection.

One autograd node replaces ``FreeTimeGaussians.at_time``, ``sh.eval_sh`` and
``project.project`` (dozens of small PyTorch operations and their autograd bookkeeping) with
one Numba forward kernel and one hand-written backward kernel (``prepare_kernels``). Outputs
agree with that PyTorch path to float32 rounding; gradients reach every model parameter.

    from ftgspp.render.prepare import prepare
    p = prepare(model.params, t, viewmat, K, centre, W, H, sh_degree, model.cfg)
    image, alpha, depth = cpu.rasterize(p.means2d, p.conics, p.colors, p.opacities, p.depths, p.radii, W, H)

Backward results are bitwise identical across runs and Numba thread counts (no reductions
across Gaussians). The inputs are kept with ``save_for_backward``, so editing a parameter in
place between forward and backward raises PyTorch's usual error instead of giving wrong
gradients.
"""

from __future__ import annotations

import functools
from typing import Mapping, NamedTuple

import numpy as np
import torch
from torch import Tensor

from ftgspp.render import prepare_kernels as _pk
from ftgspp.render.contract import EPS2D
from ftgspp.render.cpu import f32_array
from ftgspp.render.project import tangent_limits
from ftgspp.runtime.jit import configure_numba

# Model parameters the kernel reads, in kernel argument order.
PARAM_NAMES = ("means", "velocities", "times", "durations", "scales", "quats", "opacities", "gates", "sh0", "shN")


class Prepared(NamedTuple):
    """The Gaussians of a model at one time, projected into one camera."""

    means2d: Tensor  # [N, 2] pixels (zeros where culled)
    conics: Tensor  # [N, 3] upper triangle of the inverse 2D covariance (zeros where culled)
    colors: Tensor  # [N, D] SH colours along the viewing directions
    opacities: Tensor  # [N] sigmoid(o) * phi(t)
    depths: Tensor  # [N] camera-space z of the centres
    radii: Tensor  # [N, 2] int32 pixel radius per axis, 0 = culled
    temporal: Tensor  # [N] phi(t)
    means: Tensor  # [N, 3] centres at time t (world)


def camera_row(K: Tensor, width: int, height: int, near_plane: float, eps2d: float) -> np.ndarray:
    """The kernel's camera row (``prepare_kernels.CAM_*``), in project.py's float32 rounding.

    A fresh array each call; the rows of the cameras already seen are remembered (a training run
    asks for the same few every iteration, and computing one takes ~70 us of small tensor ops)."""
    k = K.detach().to("cpu", torch.float32).numpy()
    # keyed by the float32 bytes the row stores, so that -0.0 and 0.0 are two keys
    scalars = np.array([near_plane, eps2d], np.float32).tobytes()
    return _camera_row(k.tobytes(), int(width), int(height), scalars).copy()


@functools.lru_cache(maxsize=256)
def _camera_row(k_bytes: bytes, width: int, height: int, scalar_bytes: bytes) -> np.ndarray:
    k = np.frombuffer(k_bytes, np.float32).reshape(3, 3)
    near_plane, eps2d = np.frombuffer(scalar_bytes, np.float32)
    row = np.zeros(_pk.N_CAM, np.float32)
    row[_pk.CAM_FX], row[_pk.CAM_FY], row[_pk.CAM_CX], row[_pk.CAM_CY] = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    row[_pk.CAM_W], row[_pk.CAM_H], row[_pk.CAM_NEAR], row[_pk.CAM_EPS2D] = width, height, near_plane, eps2d
    row[_pk.CAM_LOX], row[_pk.CAM_HIX], row[_pk.CAM_LOY], row[_pk.CAM_HIY] = tangent_limits(torch.from_numpy(k.copy()),
                                                                                            width, height)
    return row


class _PrepareCPU(torch.autograd.Function):
    """``prepare_kernels.prepare_forward`` / ``prepare_backward`` as one autograd node."""

    @staticmethod
    def forward(ctx, settings, viewmat, centre, cam, *params):
        arrays = [f32_array(p) for p in params]
        view, ctr = f32_array(viewmat), f32_array(centre)
        outs = _pk.prepare_forward(settings[0], *arrays, view, ctr, cam, *settings[1:])
        means2d, conics, colors, opac, depths, radii, phi, means_t = (torch.from_numpy(a) for a in outs)
        ctx.settings, ctx.view, ctx.centre, ctx.cam = settings, view, ctr, cam
        ctx.gate_on = settings[3]
        ctx.save_for_backward(*params, radii)
        ctx.mark_non_differentiable(radii)
        ctx.set_materialize_grads(False)
        return means2d, conics, colors, opac, depths, radii, phi, means_t

    @staticmethod
    def backward(ctx, g_m2d, g_con, g_col, g_op, g_z, _g_radii, g_phi, g_mt):
        *params, radii = ctx.saved_tensors
        n, n_dim = params[0].shape[0], params[8].shape[2]

        def cot(g: Tensor | None, shape: tuple[int, ...]) -> np.ndarray:
            return np.zeros(shape, np.float32) if g is None else f32_array(g).reshape(shape)

        grads = _pk.prepare_backward(
            ctx.settings[0], *[f32_array(p) for p in params], ctx.view, ctx.centre, ctx.cam, *ctx.settings[1:],
            radii.numpy(), cot(g_m2d, (n, 2)), cot(g_con, (n, 3)), cot(g_col, (n, n_dim)), cot(g_op, (n,)),
            cot(g_z, (n,)), cot(g_phi, (n,)), cot(g_mt, (n, 3)),
        )  # fmt: skip
        out = [torch.from_numpy(g).to(p.dtype) for g, p in zip(grads, params)]
        if not ctx.gate_on:
            out[PARAM_NAMES.index("gates")] = None  # as in at_time: the gate is not used at all
        return (None, None, None, None, *out)


def prepare(
    params: Mapping[str, Tensor],  # the model's parameters (PARAM_NAMES), float32 on the CPU
    t: float,  # seconds
    viewmat: Tensor,  # [4, 4] world-to-camera
    K: Tensor,  # [3, 3]
    centre: Tensor,  # [3] camera centre (world)
    width: int,
    height: int,
    sh_degree: int,
    max_duration: float | None,  # None: s = exp(d)
    gate: bool,
    gate_gamma: float,
    near_plane: float = 0.01,
    eps2d: float = EPS2D,
) -> Prepared:
    """Evaluate, colour and project every Gaussian at time ``t`` (see the module docstring)."""
    configure_numba()  # before the first parallel kernel fixes Numba's threading layer
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
    cam = camera_row(K, int(width), int(height), near_plane, eps2d)
    outs = _PrepareCPU.apply(settings, viewmat, centre, cam, *(params[k] for k in PARAM_NAMES))
    return Prepared(*outs)
