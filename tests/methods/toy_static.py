"""A method written outside the ``ftgspp`` package, as docs/methods.md tells a newcomer to:
static 3D Gaussians (3DGS with no time), selected with ``model.method=tests.methods.toy_static:StaticGaussians``.

Each Gaussian has a position, a quaternion, log-scales, an opacity logit and an RGB colour;
nothing depends on t, so φ(t) = 1, every Gaussian lives for ever and nothing moves.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import torch

from ftgspp.methods import DynamicGaussians, GaussiansAt


class StaticGaussians(DynamicGaussians):
    LR_KEYS: ClassVar[dict[str, str]] = {"rgb": "sh0"}  # reuse an existing learning rate for the colour

    @classmethod
    def from_points(cls, means, colors, times, velocities, spacing, cfg, init, device="cpu"):
        n = len(means)
        f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
        return cls({
            "means": f32(means),
            "quats": f32([1.0, 0.0, 0.0, 0.0]).repeat(n, 1),
            "scales": torch.log(0.5 * f32(spacing).clamp_min(1e-7))[:, None].repeat(1, 3),
            "opacities": torch.full((n,), math.log(0.3 / 0.7), device=device),
            "rgb": f32(colors),
        }, cfg)

    def temporal_opacity(self, t):
        return torch.ones_like(self.params["opacities"])

    def temporal_centres(self):
        return torch.zeros_like(self.params["opacities"])

    def lifetimes(self, threshold):
        alive = self.base_opacity() >= threshold
        return torch.where(alive, math.inf, 0.0)

    def at_time(self, t):
        p = self.params
        return GaussiansAt(means=p["means"], quats=p["quats"], opacities=self.base_opacity(),
                           temporal=self.temporal_opacity(t), log_scales=p["scales"], colors=p["rgb"])
