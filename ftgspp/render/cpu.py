"""The ``cpu`` rasterization backend: compiled Numba kernels with a hand-written backward.

Same contract and results as ``reference.rasterize`` (ftgspp/render/contract.py), two to three
orders of magnitude faster on CPU. Maths is float32; outputs come back in the dtype and on
the device of ``means2d``. Gradients flow to ``means2d``, ``conics``, ``colors``,
``opacities``, ``depths`` and ``background``, and are bitwise identical from run to run and
for any Numba thread count (``numba.set_num_threads``).

    from ftgspp.render.cpu import rasterize
    image, alpha, depth = rasterize(means2d, conics, colors, opacities, depths, radii, W, H, bg)

Threading: ``rasterize`` calls ``ftgspp.runtime.jit.configure_numba()`` before its first
parallel kernel, which picks Numba's OpenMP layer (it starts a parallel region in a few
microseconds; ``workqueue`` takes tens to hundreds); ``NUMBA_THREADING_LAYER`` overrides the
choice. The OpenMP runtime is PyTorch's too, so ``NUMBA_NUM_THREADS=1`` also caps
PyTorch at one thread (``numba.set_num_threads`` does not). Like PyTorch's own OpenMP
parallelism it is not fork-safe: a process forked after parallel work hangs or aborts in its
next parallel region, so start worker processes with ``spawn`` (or as subprocesses).

Compilation: the kernels compile on first use (about 25 s on a 2-core machine) and are
cached on disk (``NUMBA_CACHE_DIR``, else ``__pycache__`` next to the module); later
processes load them in under a second. The process that compiled the rasterizer runs it as
fast as one that loaded it (``_TILE_JIT`` in ``cpu_kernels``).
"""

from __future__ import annotations

import numba
import numpy as np
import torch
from torch import Tensor

from ftgspp.render import cpu_kernels as _k
from ftgspp.runtime.jit import configure_numba


def threading_layer() -> str:
    """The Numba threading layer in use (known once a parallel kernel has run)."""
    try:
        return numba.threading_layer()
    except ValueError:
        return f"not started (requested {numba.config.THREADING_LAYER})"


def depth_sort_keys(depths: np.ndarray) -> np.ndarray:
    """uint32 keys whose unsigned order is the numeric order of float32 ``depths`` [N].

    Positive floats keep their bit order once the sign bit is set; negative ones are
    bit-inverted. ``-0.0`` is folded onto ``+0.0`` so that equal depths tie (then the
    index decides, as in a stable sort).
    """
    bits = (depths.astype(np.float32) + np.float32(0.0)).view(np.uint32)
    negative = (bits & np.uint32(0x80000000)) != 0
    return np.where(negative, ~bits, bits | np.uint32(0x80000000)).astype(np.uint32)


def f32_array(t: Tensor) -> np.ndarray:
    """Contiguous float32 numpy array of ``t`` (a view when ``t`` already is one, on the CPU)."""
    t = t.detach()
    if t.dtype != torch.float32 or t.device.type != "cpu":  # the check is cheaper than a no-op .to()
        t = t.to("cpu", torch.float32)
    return np.ascontiguousarray(t.numpy())


def _forward(
    m2d, con, col, opa, dep, bg, rad, width: int, height: int
) -> tuple[_k.Binning, _k.Forward]:
    """Bin, balance and composite (float32 numpy in, kernel outputs out)."""
    binning = _k.bin_gaussians(m2d, con, opa, rad, width, height)
    if len(binning.offsets) > 1 and np.diff(binning.offsets).max() >= _k.MAX_TILE_LIST:
        raise ValueError(
            f"more than {_k.MAX_TILE_LIST} Gaussians overlap one 16x16 tile; the cpu backend cannot render that"
        )
    workers = _k.balance_tiles(binning.tile_cost, numba.get_num_threads())
    fwd = _k.render_forward(
        m2d, con, col, opa, dep, depth_sort_keys(dep), bg, binning.offsets, binning.pair_gauss, binning.span,
        binning.rect, binning.gauss_off, *workers, width, height,
    )  # fmt: skip  (also depth-sorts binning.pair_gauss per tile)
    return binning, fwd


class _RasterizeCPU(torch.autograd.Function):
    """Forward and backward kernels of ``cpu_kernels`` as one autograd node."""

    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, background, radii, width, height):
        inputs = (means2d, conics, colors, opacities, depths, background)
        arrays = [f32_array(t) for t in inputs]  # views of float32 CPU tensors
        rad = np.ascontiguousarray(radii.detach().to("cpu", torch.int64).numpy())  # [N, 2]
        binning, fwd = _forward(*arrays, rad, width, height)
        # Saved, not copied: editing an input in place before backward raises PyTorch's error.
        ctx.save_for_backward(*inputs)
        ctx.binning, ctx.fwd = binning, fwd
        ctx.in_dtypes = [t.dtype for t in (means2d, conics, colors, opacities, depths, background)]
        ctx.device = means2d.device

        def out(a: np.ndarray) -> Tensor:
            return torch.from_numpy(a).to(device=means2d.device, dtype=means2d.dtype)

        return out(fwd.image), out(fwd.alpha[..., None]), out(fwd.depth[..., None])

    @staticmethod
    def backward(ctx, grad_image, grad_alpha, grad_depth):
        m2d, con, col, opa, dep, bg = [f32_array(t) for t in ctx.saved_tensors]
        binning, fwd = ctx.binning, ctx.fwd
        height, width, n_dim = fwd.image.shape

        def cotangent(g: Tensor | None, shape: tuple[int, ...]) -> np.ndarray:
            return np.zeros(shape, np.float32) if g is None else f32_array(g).reshape(shape)

        workers = _k.balance_tiles(fwd.tile_work, numba.get_num_threads())
        pair_grads, bg_grads = _k.render_backward(
            m2d, con, col, opa, dep, bg, binning.offsets, binning.pair_gauss, fwd.n_used,
            fwd.pair_live, fwd.pair_box, *workers, fwd.t_final, fwd.stop_slot,
            cotangent(grad_image, (height, width, n_dim)), cotangent(grad_alpha, (height, width)),
            cotangent(grad_depth, (height, width)),
        )  # fmt: skip
        parts = _k.reduce_pair_grads(pair_grads, binning.gauss_off, fwd.gauss_pairs, bg_grads)
        # means2d, conics, colors, opacities, depths (float32), background (float64)
        out = [torch.from_numpy(p).to(device=ctx.device, dtype=dt) for p, dt in zip(parts, ctx.in_dtypes)]
        return (*out, None, None, None)


def rasterize(
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3] (a, b, c) upper triangle of the inverse 2D covariance
    colors: Tensor,  # [N, D]
    opacities: Tensor,  # [N] in [0, 1]
    depths: Tensor,  # [N]
    radii: Tensor,  # [N, 2] int, 0 = culled
    width: int,
    height: int,
    background: Tensor | None = None,  # [D]
) -> tuple[Tensor, Tensor, Tensor]:
    """Composite projected Gaussians -> (image [H, W, D], alpha [H, W, 1], depth [H, W, 1])."""
    configure_numba()  # before the first parallel kernel fixes Numba's threading layer
    n = means2d.shape[0]
    if colors.dim() != 2 or colors.shape[0] != n:
        raise ValueError(f"colors must be [N={n}, D], got {tuple(colors.shape)}")
    for name, t, shape in (
        ("means2d", means2d, (n, 2)),
        ("conics", conics, (n, 3)),
        ("opacities", opacities, (n,)),
        ("depths", depths, (n,)),
        ("radii", radii, (n, 2)),
    ):
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} must have shape {shape}, got {tuple(t.shape)}")
    if background is None:
        background = colors.new_zeros(colors.shape[1])
    elif tuple(background.shape) != (colors.shape[1],):
        raise ValueError(f"background must have shape ({colors.shape[1]},), got {tuple(background.shape)}")
    return _RasterizeCPU.apply(means2d, conics, colors, opacities, depths, background, radii, int(width), int(height))
