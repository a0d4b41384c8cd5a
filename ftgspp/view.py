"""Render a model (any ``DynamicGaussians`` method) from a ``Camera`` at a time t.

Glue between the model (4D parameters), the colour model and the rasterizer backends. On the
``cpu`` backend a method that has a fused stage of its own (``prepare_cpu``: time evaluation,
SH colour and projection as one Numba node, ``render.prepare``) renders through it; every other
method and backend composes the PyTorch modules (``model.at_time``, ``render.sh.eval_sh``
unless the method gives RGB, ``render.project``), and ``reference`` stays the pure-autograd
oracle of both.
"""

from __future__ import annotations

import torch

from ftgspp.data.scene import Camera
from ftgspp.methods.base import DynamicGaussians, GaussiansAt
from ftgspp.render import RenderOutput, render, resolve_backend
from ftgspp.render.contract import CameraTensors, Projected
from ftgspp.render.sh import eval_sh


def camera_tensors(cam: Camera, device: torch.device | str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(viewmat [4, 4], K [3, 3], centre [3])`` as float32 tensors on ``device``."""
    f = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)  # noqa: E731
    return f(cam.viewmat), f(cam.K), f(cam.center)


def render_view(
    model: DynamicGaussians,
    cam: Camera,
    t: float,
    sh_degree: int,
    background: torch.Tensor | None = None,  # [3]
    backend: str = "auto",
    colors: torch.Tensor | None = None,  # [N, D] to composite instead of SH colours
) -> tuple[RenderOutput, GaussiansAt]:
    """Render ``model`` at time ``t`` seconds; returns the render and the Gaussians used.

    ``out.means2d.grad`` holds the screen-space gradient after ``backward()``.
    """
    means = model.params["means"]
    viewmat, K, centre = camera_tensors(cam, means.device)
    name = resolve_backend(backend, means.device)
    if name == "cpu" and means.device.type == "cpu" and means.dtype == torch.float32:
        camera = CameraTensors(viewmat, K, centre, cam.width, cam.height)
        fused = model.prepare_cpu(t, camera, sh_degree if colors is None else 0)
        if fused is not None:
            projected, g = fused
            return _rasterize_cpu(projected, colors, cam, background), g
    g = model.at_time(t)
    if colors is None and g.colors is not None:  # the method's own view-independent RGB
        colors = g.colors
    if colors is None:
        dirs = g.means - centre
        dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-8)
        colors = eval_sh(sh_degree, g.sh, dirs)
    out = render(g.means, g.quats, g.scales, g.opacities, colors, viewmat, K, cam.width, cam.height,
                 background=background, backend=name)
    return out, g


def _rasterize_cpu(
    p: Projected, colors: torch.Tensor | None, cam: Camera, background: torch.Tensor | None
) -> RenderOutput:
    """The ``cpu`` rasterizer on a fused stage's projected Gaussians (``colors`` instead of theirs)."""
    from ftgspp.render.cpu import rasterize

    means2d = p.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    image, alpha, depth = rasterize(means2d, p.conics, p.colors if colors is None else colors, p.opacities, p.depths,
                                    p.radii, cam.width, cam.height, background)  # fmt: skip
    return RenderOutput(image, alpha, depth, means2d, p.radii, p.depths, stage="fused")
