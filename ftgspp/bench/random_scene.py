"""The random scene ``ftgspp bench render`` times: 3D Gaussians in front of a camera, and
their projection (the rasterizer inputs every backend is given).

    inputs = project_scene(random_scene(5000, 128, 96))  # means2d, conics, ..., radii
"""

from __future__ import annotations

import math
from typing import Any

import torch


def random_scene(n: int, width: int, height: int, seed: int = 0) -> dict[str, Any]:
    """``n`` random 3D Gaussians filling the view of a pinhole camera at the origin.

    Centres are uniform in screen space (10% margin) at depths 2..10; each axis has a
    screen-space standard deviation log-uniform in [0.5, 3] px; opacities uniform in
    [0.05, 1]; RGB colours uniform. Returns the 3D parameters plus ``viewmat`` and ``K``.
    """
    g = torch.Generator().manual_seed(seed)
    focal = 1.2 * width
    K = torch.tensor([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    z = 2.0 + 8.0 * torch.rand(n, generator=g)
    u = (torch.rand(n, generator=g) * 1.2 - 0.1) * width
    v = (torch.rand(n, generator=g) * 1.2 - 0.1) * height
    means = torch.stack([(u - K[0, 2]) * z / focal, (v - K[1, 2]) * z / focal, z], dim=-1)
    sigma_px = torch.exp(math.log(0.5) + math.log(6.0) * torch.rand(n, 3, generator=g))
    return dict(
        means=means,  # [N, 3]
        quats=torch.randn(n, 4, generator=g),  # [N, 4]
        scales=sigma_px * z.unsqueeze(-1) / focal,  # [N, 3]
        opacities=0.05 + 0.95 * torch.rand(n, generator=g),  # [N]
        colors=torch.rand(n, 3, generator=g),  # [N, 3]
        viewmat=torch.eye(4),
        K=K,
        width=width,
        height=height,
    )


def project_scene(scene: dict[str, Any]) -> dict[str, Any]:
    """The rasterizer inputs of ``scene`` (detached): means2d, conics, colors, ..., radii."""
    from ftgspp.render.project import project

    with torch.no_grad():
        means2d, conics, depths, radii, _ = project(
            scene["means"], scene["quats"], scene["scales"], scene["viewmat"], scene["K"],
            scene["width"], scene["height"], opacities=scene["opacities"],
        )  # fmt: skip
    return dict(
        means2d=means2d, conics=conics, colors=scene["colors"], opacities=scene["opacities"],
        depths=depths, radii=radii, width=scene["width"], height=scene["height"],
        background=torch.full((scene["colors"].shape[1],), 0.5),
    )  # fmt: skip
