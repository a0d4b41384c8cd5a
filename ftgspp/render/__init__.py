"""One ``render()`` entry point over several rasterization backends.

Backends share the EWA projection (``project.py``, plain PyTorch autograd) and the
rasterizer contract and conventions of ``contract.py`` (gsplat 1.5.3's), and differ in how
they composite the projected 2D Gaussians:

- ``reference``: pure PyTorch autograd, tile-masked like a tile rasterizer. The oracle.
- ``cpu``: compiled Numba kernels with a hand-written backward (fast on CPU).
- ``gsplat``: ``gsplat.rasterization`` on CUDA (optional extra; every gsplat call is in
  ``gsplat_adapter.py``; checked against ``reference`` on CPU by running gsplat's Python
  code over torch stand-ins of its CUDA ops, ``tests/render/gsplat_standins.py``).

A method may bring a fused stage of its own for the ``cpu`` backend (its time evaluation in
Numba kernels that hand each block of Gaussians to the shared SH colour and projection of
``prepare_kernels.py``, run as one autograd node by ``prepare.py``; same numbers to float32
rounding); ``view.render_view`` then uses it before the ``cpu`` rasterizer instead of this
projection. This package knows no method.

``backend="auto"`` picks gsplat on CUDA tensors and cpu otherwise (falling back to the
reference when a backend is not installed). ``resolve_backend`` is where gsplat's
requirements (installed, CUDA tensors) are checked.

    out = render(means, quats, scales, opacities, colors, viewmat, K, W, H, backend="auto")
    out.image.sum().backward(); score = out.means2d.grad.norm(dim=-1)
"""

from __future__ import annotations

import importlib
import importlib.util

import torch

from ftgspp.render.contract import Rasterize, RenderOutput

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
    """Concrete backend name for ``backend`` ("auto": gsplat on CUDA, else cpu, else reference).

    ``"gsplat"`` on a non-CUDA ``device``, or without gsplat installed, is a RuntimeError.
    """
    if backend == "gsplat":
        if device.type != "cuda":
            raise RuntimeError("render backend 'gsplat' needs CUDA tensors")
        if not _gsplat_available():
            raise RuntimeError("render backend 'gsplat' is unavailable: gsplat is not installed")
        return backend
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
        from ftgspp.render import gsplat_adapter

        return gsplat_adapter.render(means, quats, scales, opacities, colors, viewmat, K, width, height,
                                     background, near_plane)  # fmt: skip
    rasterize = _import_backend(name)
    from ftgspp.render.project import project

    means2d, conics, depths, radii, _ = project(means, quats, scales, viewmat, K, width, height, near_plane,
                                                opacities=opacities)  # fmt: skip
    if means2d.requires_grad:
        means2d.retain_grad()
    image, alpha, depth = rasterize(means2d, conics, colors, opacities, depths, radii, width, height, background)
    return RenderOutput(image, alpha, depth, means2d, radii, depths)
