"""The fused per-Gaussian stage of the ``cpu`` backend, for the methods that supply one.

A method may render on the ``cpu`` backend through a fused stage of its own (its
``prepare_cpu``): one Numba forward kernel and one hand-written backward kernel that evaluate its
Gaussians at time t, colour them (by SH along the viewing direction, or the method's own RGB) and
project them, where the generic path runs its ``at_time``, ``sh.eval_sh`` and ``project.project``
as dozens of small PyTorch operations and their autograd bookkeeping. The method's kernels
evaluate time; the projection, the SH colour and their chain rule are the shared block functions
of ``prepare_kernels``. This module runs such a pair as one autograd node:

    kernels = FusedKernels(forward, backward)
    p = fused_prepare(kernels, [params[k] for k in NAMES], settings, camera)
    image, alpha, depth = cpu.rasterize(*p.projected, W, H)

The kernel pair's contract (float32 NumPy arrays in and out, the parameters in one order):

    forward(*params, view [4, 4], centre [3], cam [N_CAM], *settings)
        -> means2d [N, 2], conics [N, 3], colors [N, D], opacities [N], depths [N],
           radii [N, 2] int32, temporal [N] (phi(t)), means [N, 3] (the centres at time t)
    backward(*params, view, centre, cam, *settings, radii, and the cotangent of every forward
             output but radii, in order) -> the gradient of every parameter, in order

The inputs are kept with ``save_for_backward``, so editing a parameter in place between forward
and backward raises PyTorch's usual error instead of giving wrong gradients.
"""

from __future__ import annotations

import functools
from typing import Callable, NamedTuple, Sequence

import numpy as np
import torch
from torch import Tensor

from ftgspp.render import prepare_kernels as _pk
from ftgspp.render.contract import EPS2D, CameraTensors, Projected
from ftgspp.render.cpu import f32_array
from ftgspp.render.project import tangent_limits
from ftgspp.runtime.jit import configure_numba


class FusedKernels(NamedTuple):
    """A method's fused stage: its Numba forward and backward kernels (the module docstring)."""

    forward: Callable[..., tuple]
    backward: Callable[..., tuple]


class Prepared(NamedTuple):
    """The Gaussians of a model at one time, projected into one camera."""

    means2d: Tensor  # [N, 2] pixels (zeros where culled)
    conics: Tensor  # [N, 3] upper triangle of the inverse 2D covariance (zeros where culled)
    colors: Tensor  # [N, D] colours (SH along the viewing directions, or the method's RGB)
    opacities: Tensor  # [N] sigmoid(o) * phi(t)
    depths: Tensor  # [N] camera-space z of the centres
    radii: Tensor  # [N, 2] int32 pixel radius per axis, 0 = culled
    temporal: Tensor  # [N] phi(t)
    means: Tensor  # [N, 3] centres at time t (world)

    @property
    def projected(self) -> Projected:
        """What the rasterizer takes."""
        return Projected(self.means2d, self.conics, self.colors, self.opacities, self.depths, self.radii)


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
    """A method's ``FusedKernels`` as one autograd node."""

    @staticmethod
    def forward(ctx, kernels, settings, no_grad, viewmat, centre, cam, *params):
        arrays = [f32_array(p) for p in params]
        view, ctr = f32_array(viewmat), f32_array(centre)
        outs = kernels.forward(*arrays, view, ctr, cam, *settings)
        means2d, conics, colors, opac, depths, radii, phi, means_t = (torch.from_numpy(a) for a in outs)
        ctx.kernels, ctx.settings, ctx.no_grad = kernels, settings, no_grad
        ctx.view, ctx.centre, ctx.cam, ctx.n_dim = view, ctr, cam, colors.shape[1]
        ctx.save_for_backward(*params, radii)
        ctx.mark_non_differentiable(radii)
        ctx.set_materialize_grads(False)
        return means2d, conics, colors, opac, depths, radii, phi, means_t

    @staticmethod
    def backward(ctx, g_m2d, g_con, g_col, g_op, g_z, _g_radii, g_phi, g_mt):
        *params, radii = ctx.saved_tensors
        n = radii.shape[0]

        def cot(g: Tensor | None, shape: tuple[int, ...]) -> np.ndarray:
            return np.zeros(shape, np.float32) if g is None else f32_array(g).reshape(shape)

        grads = ctx.kernels.backward(
            *[f32_array(p) for p in params], ctx.view, ctx.centre, ctx.cam, *ctx.settings, radii.numpy(),
            cot(g_m2d, (n, 2)), cot(g_con, (n, 3)), cot(g_col, (n, ctx.n_dim)), cot(g_op, (n,)), cot(g_z, (n,)),
            cot(g_phi, (n,)), cot(g_mt, (n, 3)),
        )  # fmt: skip
        out = [None if i in ctx.no_grad else torch.from_numpy(g).to(p.dtype)
               for i, (g, p) in enumerate(zip(grads, params))]  # fmt: skip
        return (None, None, None, None, None, None, *out)


def fused_prepare(
    kernels: FusedKernels,
    params: Sequence[Tensor],  # the parameters the kernels read, in their order; float32 on the CPU
    settings: tuple,  # the kernels' scalar arguments after the camera row (time, SH degree, ...)
    camera: CameraTensors,
    no_grad: frozenset[int] = frozenset(),  # indices into ``params`` that get no gradient (None)
    near_plane: float = 0.01,
    eps2d: float = EPS2D,
) -> Prepared:
    """Run a method's fused kernels as one autograd node (the module docstring)."""
    configure_numba()  # before the first parallel kernel fixes Numba's threading layer
    cam = camera_row(camera.K, int(camera.width), int(camera.height), near_plane, eps2d)
    return Prepared(*_PrepareCPU.apply(kernels, settings, no_grad, camera.viewmat, camera.centre, cam, *params))
