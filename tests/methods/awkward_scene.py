"""A camera and Gaussians of every awkward kind in front of it, for the fused stages' oracle tests
(``test_freetime_fused.py``, ``test_stg_fused.py``): ordinary, behind-camera, off-screen, huge,
tiny and needle-like Gaussians seen from a rotated, translated camera with an off-centre
principal point, so that every branch of the shared projection's hand-written backward runs."""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from ftgspp.data.scene import Camera
from ftgspp.view import render_view

W, H = 53, 41


def make_camera() -> Camera:
    R = Rotation.from_euler("xyz", [0.15, -0.25, 0.05]).as_matrix()
    K = np.array([[45.0, 0.0, 24.0], [0.0, 47.0, 22.5], [0.0, 0.0, 1.0]])
    return Camera("cam", K, R, np.array([0.2, -0.1, 0.3]), W, H)


def awkward_gaussians(g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """World positions ``[N, 3]`` and log scales ``[N, 3]`` (float32, N = 92) of Gaussians of every
    awkward kind, placed in the frame of ``make_camera``; draws from ``g``."""

    def rand(*shape):
        return torch.rand(*shape, generator=g)

    def randn(*shape):
        return torch.randn(*shape, generator=g)

    tan = torch.tensor([W / 2 / 45.0, H / 2 / 47.0])
    parts = []

    def add(n, uv, z, log_scale):  # uv in units of the half field of view, z camera depth
        xy = uv * tan * z[:, None]
        parts.append((torch.cat([xy, z[:, None]], -1), log_scale))

    n = 60  # ordinary
    add(n, rand(n, 2) * 2.2 - 1.1, 2 + 4 * rand(n), math.log(0.03) + rand(n, 3))
    n = 8  # behind the camera or inside the near plane
    add(n, rand(n, 2) * 2 - 1, -1 + 1.005 * rand(n), math.log(0.05) + rand(n, 3))
    n = 8  # off-screen, beyond the tangent clamp (some still reach into the image)
    add(n, torch.sign(randn(n, 2)) * (1.4 + 2 * rand(n, 2)), 2 + 3 * rand(n), math.log(0.3) + 2 * rand(n, 3))
    n = 4  # huge
    add(n, rand(n, 2) * 2 - 1, 3 + rand(n), math.log(2.0) + rand(n, 3))
    n = 6  # tiny: the low-pass dominates
    add(n, rand(n, 2) * 2 - 1, 2 + 3 * rand(n), math.log(1e-4) + rand(n, 3))
    n = 6  # needles: one long axis, two very thin ones
    ls = torch.stack([math.log(0.5) + rand(n), math.log(1e-3) + rand(n), math.log(1e-3) + rand(n)], -1)
    add(n, rand(n, 2) * 2 - 1, 2 + 3 * rand(n), ls)
    p_cam = torch.cat([p for p, _ in parts]).double()
    log_scales = torch.cat([s for _, s in parts])
    cam = make_camera()
    world = ((p_cam - torch.from_numpy(cam.T)) @ torch.from_numpy(cam.R)).float()  # R^T (p - T)
    return world, log_scales


def render_both_backends(make_model, t: float, sh_degree: int) -> dict[str, tuple]:
    """``{backend: (render, Gaussians at t, gradients)}`` for ``cpu`` and ``reference``: a fresh
    ``make_model()`` each, rendered from ``make_camera()`` at ``t`` and differentiated through a loss
    of image, depth, alpha and the temporal weight; the gradients are every parameter's and the
    screen-space one (``means2d``) the relocation statistics read."""
    cam = make_camera()
    results = {}
    for backend in ("cpu", "reference"):
        model = make_model()
        out, g = render_view(model, cam, t, sh_degree, background=torch.tensor([0.2, 0.5, 0.7]), backend=backend)
        weight = torch.linspace(0, 1, W).view(1, -1, 1)
        loss = (out.image * weight).sum() + out.depth.mean() + out.alpha.sum() + g.temporal.sum()
        loss.backward()
        grads = {k: p.grad for k, p in model.params.items()} | {"means2d": out.means2d.grad}
        results[backend] = (out, g, grads)
    return results
