"""One ``render()`` entry point over several rasterization backends.

Backends share the EWA projection (``project.py``, plain PyTorch autograd) and the
rasterizer contract and conventions of ``contract.py``, and differ in how they composite
the projected 2D Gaussians:

- ``reference``: pure PyTorch autograd, tile-masked like a tile rasterizer. The oracle.
- ``cpu``: compiled Numba kernels with a hand-written backward (fast on CPU).
- ``gsplat``: ``gsplat.rasterization`` on CUDA (optional extra).

For a ``FreeTimeGaussians`` model, ``view.render_view`` on the ``cpu`` backend replaces
time evaluation, SH colour and this projection by one fused Numba node (``prepare.py``,
same numbers to float32 rounding) before the ``cpu`` rasterizer.

``backend="auto"`` picks gsplat on CUDA tensors and cpu otherwise (falling back to the
reference when a backend is not installed).

    out = render(means, quats, scales, opacities, colors, viewmat, K, W, H, backend="auto")
    out.image.sum().backward(); score = out.means2d.grad.norm(dim=-1)
"""

from __future__ import annotations

import importlib
import importlib.util

import torch

from ftgspp.render.contract import EPS2D, TILE_SIZE, Rasterize, RenderOutput

BACKENDS = ("reference", "cpu", "gsplat", "auto")


def _import_backend(name: str) -> Rasterize:
    """The ``rasterize`` function of a backend, imported on first use."""
    if name == "reference":
        from ftgspp.render.reference import rasterize

        return rasterize
    if name == "cpu":
        try:
            module = importlib.import_module("ftgspp.render.cpu")
        except ImportError as err:
            raise RuntimeError(f"render backend 'cpu' is unavailable: {err}") from err
        return module.rasterize
    raise ValueError(f"unknown render backend {name!r}; choose one of {BACKENDS}")


def _gsplat_available() -> bool:
    return importlib.util.find_spec("gsplat") is not None


def resolve_backend(backend: str, device: torch.device) -> str:
    """Concrete backend name for ``backend`` ("auto": gsplat on CUDA, else cpu, else reference)."""
    if backend != "auto":
        if backend not in BACKENDS:
            raise ValueError(f"unknown render backend {backend!r}; choose one of {BACKENDS}")
        return backend
    if device.type == "cuda" and _gsplat_available():
        return "gsplat"
    try:
        _import_backend("cpu")
        return "cpu"
    except RuntimeError:
        return "reference"


def render(
    means: torch.Tensor,  # [N, 3] world
    quats: torch.Tensor,  # [N, 4] (w, x, y, z), any norm
    scales: torch.Tensor,  # [N, 3] activated
    opacities: torch.Tensor,  # [N] in [0, 1]
    colors: torch.Tensor,  # [N, D]
    viewmat: torch.Tensor,  # [4, 4] world-to-camera
    K: torch.Tensor,  # [3, 3] OpenCV intrinsics (pixel centres at integers)
    width: int,
    height: int,
    background: torch.Tensor | None = None,  # [D]
    backend: str = "reference",
    near_plane: float = 0.01,
) -> RenderOutput:
    """Render 3D Gaussians from one camera: EWA projection, then the backend's rasterizer.

    ``out.means2d.grad`` holds the screen-space gradient after ``backward()``.
    """
    name = resolve_backend(backend, means.device)
    if name == "gsplat":
        return _render_gsplat(means, quats, scales, opacities, colors, viewmat, K, width, height,
                              background, near_plane)  # fmt: skip
    rasterize = _import_backend(name)
    from ftgspp.render.project import project

    means2d, conics, depths, radii, _ = project(means, quats, scales, viewmat, K, width, height, near_plane)
    if means2d.requires_grad:
        means2d.retain_grad()
    image, alpha, depth = rasterize(means2d, conics, colors, opacities, depths, radii, width, height, background)
    return RenderOutput(image, alpha, depth, means2d, radii, depths)


def _render_gsplat(
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None,
    near_plane: float,
) -> RenderOutput:
    """``gsplat.rasterization`` (its own CUDA projection, same EWA conventions, eps2d 0.3).

    gsplat puts pixel centres at half-integers, so the principal point is shifted by +0.5;
    its ``means2d`` (returned as is, for its gradient) are therefore offset by +0.5 px.
    """
    if not means.is_cuda:
        raise RuntimeError("render backend 'gsplat' needs CUDA tensors")
    try:
        import gsplat
    except ImportError as err:
        raise RuntimeError(f"render backend 'gsplat' is unavailable: {err}") from err
    K_gs = K.clone()
    K_gs[0, 2] += 0.5
    K_gs[1, 2] += 0.5
    bg = None if background is None else background.reshape(1, -1)
    rgbd, alpha, meta = gsplat.rasterization(
        means, quats, scales, opacities, colors, viewmat[None], K_gs[None], width, height,
        near_plane=near_plane, eps2d=EPS2D, tile_size=TILE_SIZE, render_mode="RGB+D",
        backgrounds=bg, packed=False,
    )  # fmt: skip
    batched = meta["means2d"]  # [1, N, 2]
    means2d = batched[0]  # [N, 2]; not itself in the graph, so its grad is copied in by a hook
    if batched.requires_grad:
        means2d.retain_grad()
        batched.register_hook(lambda grad: setattr(means2d, "grad", grad[0]))
    radii = meta["radii"][0]
    if radii.dim() == 2:  # gsplat >= 1.5 returns per-axis radii
        radii = radii.max(dim=-1).values
    return RenderOutput(rgbd[0, ..., :-1], alpha[0], rgbd[0, ..., -1:], means2d, radii, meta["depths"][0])
