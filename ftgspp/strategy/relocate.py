"""The relocation step of the trainer: schedule, statistics and the three policies.

- ``mcmc``: sources and their copies share the source's opacity and scale by the
  3DGS-MCMC rule, so the rendered image changes as little as possible.
- ``exact_copy``: dead Gaussians become exact copies of their sources.
- ``partial_copy``: copy everything but opacity and scale, which the dead Gaussian keeps.

Adam moments of the sources are zeroed (``reset_moments="sources"``, as gsplat 1.5.3's
``strategy.ops.relocate`` does); ``"moved"`` zeroes the destinations' too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from numba import njit
from torch import nn

from ftgspp.config import StrategyConfig
from ftgspp.errors import InputError
from ftgspp.runtime.jit import JIT
from ftgspp.strategy.ops import copy_gaussians, reset_moments
from ftgspp.strategy.policies import (
    DEAD_RULES,
    MCMC_CLAMPS,
    MOMENT_RESETS,
    POLICIES,
    choose_relocation,
    mcmc_opacity_scale,
)


@dataclass
class Relocator:
    """Hyperparameters of relocation; running statistics live in the ``state`` dict."""

    cfg: StrategyConfig

    def __post_init__(self) -> None:
        for key, value, allowed in (("relocation", self.cfg.relocation, POLICIES),
                                    ("mcmc_clamp", self.cfg.mcmc_clamp, MCMC_CLAMPS),
                                    ("reset_moments", self.cfg.reset_moments, MOMENT_RESETS),
                                    ("dead", self.cfg.dead, DEAD_RULES)):
            if value not in allowed:
                raise InputError(f"strategy.{key}", f"unknown value '{value}' (choose from {', '.join(allowed)})")

    def initialize_state(self, n: int, device: torch.device | str = "cpu") -> dict[str, torch.Tensor]:
        """Per-Gaussian accumulators of the 2D mean-gradient norm, on the parameters' device."""
        return {"grad2d": torch.zeros(n, device=device), "count": torch.zeros(n, device=device)}

    @torch.no_grad()
    def accumulate(self, state: dict[str, torch.Tensor], means2d_grad: torch.Tensor, radii: torch.Tensor) -> None:
        """Add ‖∇ means2d‖ of the visible Gaussians (radii [N, 2] > 0) after a backward pass."""
        grad2d, count = state["grad2d"], state["count"]
        norms = means2d_grad.norm(dim=-1).to(grad2d.device)  # torch's norm: its bits differ with its kernel dispatch
        n = norms.shape[0]
        if (grad2d.device.type == radii.device.type == "cpu" and tuple(radii.shape) == (n, 2)
                and grad2d.shape == count.shape == norms.shape
                and grad2d.dtype == count.dtype == norms.dtype == torch.float32):
            # one pass instead of five tensor operations; the same bits (the adds below, row by row)
            _add_visible(grad2d.numpy(), count.numpy(), norms.numpy(), radii.contiguous().numpy())
            return
        # Elsewhere (a GPU), masked adds instead of boolean indexing (half the time; the same bits:
        # adding 0.0 to a non-negative sum keeps it, and each row's norm does not depend on the others).
        visible = (radii > 0).all(dim=-1).to(grad2d.device)
        grad2d.add_(torch.where(visible, norms, 0.0))
        count.add_(visible)

    def due(self, step: int) -> bool:
        """Relocate after ``step`` (1-based)?"""
        c = self.cfg
        return c.refine_start_iter < step < c.refine_stop_iter and step % c.refine_every == 0

    @torch.no_grad()
    def step(
        self,
        params: nn.ParameterDict,
        optimizer: torch.optim.Optimizer,
        state: dict[str, torch.Tensor],
        generator: torch.Generator,
        clip_opacity: torch.Tensor | None = None,
    ) -> int:
        """Relocate dead Gaussians; returns how many moved. Resets the statistics.

        ``clip_opacity`` ``[N]``: the opacity each Gaussian reaches within the clip
        (``FreeTimeGaussians.peak_opacity``); with ``strategy.dead=clip_opacity`` a Gaussian is
        also dead when it is at most ``min_opacity``."""
        opacity = torch.sigmoid(params["opacities"].detach()).cpu()
        grad2d = (state["grad2d"] / state["count"].clamp_min(1)).cpu()
        faded = None
        if self.cfg.dead == "clip_opacity":
            if clip_opacity is None:
                raise ValueError("strategy.dead=clip_opacity needs each Gaussian's opacity within the clip")
            faded = clip_opacity.detach().cpu() <= self.cfg.min_opacity
        dead, sources = choose_relocation(opacity, grad2d, self.cfg.min_opacity, generator, faded)
        state["grad2d"].zero_()
        state["count"].zero_()
        if len(dead) == 0:
            return 0
        device = params["means"].device
        dead, sources = dead.to(device), sources.to(device)
        policy = self.cfg.relocation
        if policy == "mcmc":
            n = torch.bincount(sources, minlength=len(opacity))[sources] + 1
            o_new, s_new = mcmc_opacity_scale(
                opacity.to(device)[sources], torch.exp(params["scales"].detach()[sources]), n, self.cfg.min_opacity,
                self.cfg.mcmc_clamp,
            )
            params["opacities"].data[sources] = torch.logit(o_new)
            params["scales"].data[sources] = torch.log(s_new)
            copy_gaussians(params, dead, sources)
        elif policy == "exact_copy":
            copy_gaussians(params, dead, sources)
        else:  # partial_copy
            copy_gaussians(params, dead, sources, keep=("opacities", "scales"))
        moved = sources if self.cfg.reset_moments == "sources" else torch.cat([dead, sources])
        reset_moments(optimizer, params, moved)
        return len(dead)


@njit(**JIT)
def _add_visible(grad2d: np.ndarray, count: np.ndarray, norms: np.ndarray, radii: np.ndarray) -> None:
    """grad2d[i] += norms[i] and count[i] += 1 where both radii of row i are > 0 (float32, in place)."""
    one = np.float32(1.0)
    for i in range(norms.shape[0]):
        if radii[i, 0] > 0 and radii[i, 1] > 0:
            grad2d[i] += norms[i]
            count[i] += one
