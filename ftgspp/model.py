"""``FreeTimeGaussians``: 4D Gaussians that live for a while and move freely.

Each Gaussian has a spatial mean μx, a temporal centre μt, a duration parameter d, a
velocity v, log-scales S, a quaternion R, an opacity logit o, SH colour coefficients and
a gate logit g̃ (docs/design.md §4). At time t it is an ordinary 3D Gaussian with

    μx(t) = μx + v (t − μt),     α(t) = sigmoid(o) · φ(t),
    φ(t)  = g + (1 − g) a(t)  (gate on)   or   a(t)  (gate off),
    a(t)  = exp(−½ ((t − μt) / s)²),   g = sigmoid(γ g̃),
    s     = max_duration / 6 · sigmoid(d)  (finite max_duration)  or  exp(d).

Every per-Gaussian tensor has leading dimension N and lives in ``params``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch
from torch import nn

from ftgspp.config import InitConfig, ModelConfig

SH_C0 = 0.28209479177387814


@dataclass
class GaussiansAt:
    """The 3D Gaussians of a model evaluated at one time.

    ``scales`` (activated) and ``sh`` (DC and rest concatenated) are computed from the
    parameters on first access, so that renderers that do not need them pay nothing.
    """

    means: torch.Tensor  # [N, 3]
    quats: torch.Tensor  # [N, 4]
    opacities: torch.Tensor  # [N] sigmoid(o) * phi(t)
    temporal: torch.Tensor  # [N] phi(t)
    log_scales: torch.Tensor  # [N, 3]
    sh0: torch.Tensor  # [N, 1, 3]
    shN: torch.Tensor  # [N, K - 1, 3]

    @cached_property
    def scales(self) -> torch.Tensor:
        """Activated scales exp(S), ``[N, 3]``."""
        return torch.exp(self.log_scales)

    @cached_property
    def sh(self) -> torch.Tensor:
        """SH coefficients, ``[N, K, 3]``."""
        return torch.cat([self.sh0, self.shN], dim=1)


class FreeTimeGaussians(nn.Module):
    """Per-Gaussian parameters and their activations."""

    def __init__(self, params: dict[str, torch.Tensor], cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.params = nn.ParameterDict({k: nn.Parameter(v.contiguous()) for k, v in params.items()})

    # --- construction -------------------------------------------------------------------
    @classmethod
    def from_points(
        cls,
        means: np.ndarray,  # [N, 3]
        colors: np.ndarray,  # [N, 3] RGB in [0, 1]
        times: np.ndarray,  # [N] seconds
        velocities: np.ndarray,  # [N, 3]
        spacing: np.ndarray,  # [N] kNN spacing
        cfg: ModelConfig,
        init: InitConfig,
        device: torch.device | str = "cpu",
    ) -> "FreeTimeGaussians":
        """Build a model on ``device`` from initial points (docs/design.md §4, "Init")."""
        n = len(means)
        f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
        full = lambda value: torch.full((n,), float(value), device=device)  # noqa: E731
        n_sh = (cfg.sh_degree + 1) ** 2
        spacing_t = f32(spacing).clamp_min(1e-7)
        params = {
            "means": f32(means),
            "times": f32(times),
            "durations": full(duration_to_param(init.duration, cfg.max_duration)),
            "velocities": f32(velocities),
            "scales": torch.log(init.scale_factor * spacing_t)[:, None].repeat(1, 3),
            "quats": f32([1.0, 0.0, 0.0, 0.0]).repeat(n, 1),
            "opacities": full(math.log(init.opacity / (1 - init.opacity))),
            "sh0": ((f32(colors) - 0.5) / SH_C0)[:, None, :],
            "shN": torch.zeros(n, n_sh - 1, 3, device=device),
            "gates": full(cfg.gate_init),
        }
        return cls(params, cfg)

    def __len__(self) -> int:
        return self.params["means"].shape[0]

    # --- activations --------------------------------------------------------------------
    def temporal_scale(self) -> torch.Tensor:
        """Temporal standard deviation s in seconds, ``[N]``."""
        d = self.params["durations"]
        if self.cfg.max_duration is None:
            return torch.exp(d)
        return self.cfg.max_duration / 6.0 * torch.sigmoid(d)

    def gate(self) -> torch.Tensor:
        """Gate value g in (0, 1), ``[N]`` (zeros when the gate is switched off)."""
        if not self.cfg.gate:
            return torch.zeros_like(self.params["gates"])
        return torch.sigmoid(self.cfg.gate_gamma * self.params["gates"])

    def temporal_opacity(self, t: float) -> torch.Tensor:
        """φ(t), the temporal factor of the opacity, ``[N]``."""
        a = torch.exp(-0.5 * ((t - self.params["times"]) / self.temporal_scale()) ** 2)
        if not self.cfg.gate:
            return a
        g = self.gate()
        return g + (1.0 - g) * a

    @torch.no_grad()
    def peak_opacity(self, t0: float, t1: float) -> torch.Tensor:
        """The largest opacity o·φ(t) each Gaussian reaches for t in ``[t0, t1]``, ``[N]``: φ peaks
        at the Gaussian's own time μt (the gate only lifts it), so at μt clipped to the window."""
        t = self.params["times"].detach().clamp(t0, t1)
        return self.base_opacity() * self.temporal_opacity(t)

    def base_opacity(self) -> torch.Tensor:
        """sigmoid(o), ``[N]``."""
        return torch.sigmoid(self.params["opacities"])

    def at_time(self, t: float) -> GaussiansAt:
        """The 3D Gaussians at time ``t`` (seconds)."""
        p = self.params
        phi = self.temporal_opacity(t)
        means = p["means"] + p["velocities"] * (t - p["times"])[:, None]
        return GaussiansAt(
            means=means,
            quats=p["quats"],
            opacities=self.base_opacity() * phi,
            temporal=phi,
            log_scales=p["scales"],
            sh0=p["sh0"],
            shN=p["shN"],
        )

    def lifetimes(self, threshold: float) -> torch.Tensor:
        """Effective lifetime: how long o·φ(t) stays ≥ θ, in seconds, ``[N]``.

        Without the gate, Δt(θ) = 2 s √(2 log(o/θ)) for o > θ, else 0. With it, o·φ(t) = θ
        where a(t) = a* = (θ/o − g)/(1 − g): Δt = 2 s √(2 log(1/a*)), 0 when a* ≥ 1, and
        ``inf`` when a* ≤ 0 (o·g ≥ θ: the Gaussian never fades).
        """
        o, s = self.base_opacity(), self.temporal_scale()
        if not self.cfg.gate:
            ratio = torch.clamp(o / threshold, min=1.0)
            return 2.0 * s * torch.sqrt(2.0 * torch.log(ratio))
        g = self.gate()
        a_star = (threshold / o - g) / (1.0 - g).clamp_min(1e-12)
        life = 2.0 * s * torch.sqrt(2.0 * torch.log(1.0 / a_star.clamp(min=1e-30, max=1.0)))
        life = torch.where(a_star >= 1.0, torch.zeros_like(life), life)
        return torch.where(a_star <= 0.0, torch.full_like(life, math.inf), life)


def duration_to_param(duration: float, max_duration: float | None) -> float:
    """Inverse of the temporal-scale activation: the d that gives s = ``duration``."""
    if max_duration is None:
        return math.log(duration)
    frac = min(max(duration * 6.0 / max_duration, 1e-4), 1 - 1e-4)
    return math.log(frac / (1.0 - frac))
