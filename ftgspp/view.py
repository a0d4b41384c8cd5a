"""Render a ``FreeTimeGaussians`` model from a ``Camera`` at a time t.

Glue between the model (4D parameters), the SH colour model and the rasterizer backends.
"""

from __future__ import annotations

import torch

from ftgspp.data.scene import Camera
from ftgspp.model import FreeTimeGaussians, GaussiansAt
from ftgspp.render import RenderOutput, render
from ftgspp.render.sh import eval_sh


def camera_tensors(cam: Camera, device: torch.device | str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(viewmat [4, 4], K [3, 3], centre [3])`` as float32 tensors on ``device``."""
    f = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)  # noqa: E731
    return f(cam.viewmat), f(cam.K), f(cam.center)


def render_view(
    model: FreeTimeGaussians,
    cam: Camera,
    t: float,
    sh_degree: int,
    background: torch.Tensor | None = None,  # [3]
    backend: str = "auto",
    colors: torch.Tensor | None = None,  # [N, D] to composite instead of SH colours
) -> tuple[RenderOutput, GaussiansAt]:
    """Render ``model`` at time ``t`` seconds; returns the render and the Gaussians used."""
    device = model.params["means"].device
    viewmat, K, centre = camera_tensors(cam, device)
    g = model.at_time(t)
    if colors is None:
        dirs = g.means - centre
        dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-8)
        colors = eval_sh(sh_degree, g.sh, dirs)
    out = render(g.means, g.quats, g.scales, g.opacities, colors, viewmat, K, cam.width, cam.height,
                 background=background, backend=backend)
    return out, g
