"""Render a model (any ``DynamicGaussians`` method) from a ``Camera`` at a time t.

Glue between the model (4D parameters), the colour model and the rasterizer backends. For
FreeTimeGS on the ``cpu`` backend, time evaluation, SH colour and projection run as one
fused Numba node (``render.prepare``, the methods whose ``FUSED_CPU`` is set); every other
method and backend composes the PyTorch modules (``model.at_time``, ``render.sh.eval_sh``
unless the method gives RGB, ``render.project``), and ``reference`` stays the pure-autograd
oracle of both.
"""

from __future__ import annotations

import torch

from ftgspp.data.scene import Camera
from ftgspp.methods.base import DynamicGaussians, GaussiansAt
from ftgspp.render import RenderOutput, render, resolve_backend
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
    if model.FUSED_CPU and name == "cpu" and means.device.type == "cpu" and means.dtype == torch.float32:
        return _render_view_fused(model, cam, t, sh_degree, background, colors, viewmat, K, centre)
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


def _render_view_fused(
    model: DynamicGaussians,
    cam: Camera,
    t: float,
    sh_degree: int,
    background: torch.Tensor | None,
    colors: torch.Tensor | None,
    viewmat: torch.Tensor,
    K: torch.Tensor,
    centre: torch.Tensor,
) -> tuple[RenderOutput, GaussiansAt]:
    """The ``cpu`` path: fused prepare node, then the Numba rasterizer."""
    from ftgspp.render.cpu import rasterize
    from ftgspp.render.prepare import prepare

    p, cfg = model.params, model.cfg
    prep = prepare(p, t, viewmat, K, centre, cam.width, cam.height, sh_degree if colors is None else 0,
                   cfg.max_duration, cfg.gate, cfg.gate_gamma)  # fmt: skip
    means2d = prep.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    image, alpha, depth = rasterize(means2d, prep.conics, prep.colors if colors is None else colors, prep.opacities,
                                    prep.depths, prep.radii, cam.width, cam.height, background)  # fmt: skip
    g = GaussiansAt(means=prep.means, quats=p["quats"], opacities=prep.opacities, temporal=prep.temporal,
                    log_scales=p["scales"], sh0=p["sh0"], shN=p["shN"])  # fmt: skip
    return RenderOutput(image, alpha, depth, means2d, prep.radii, prep.depths), g
