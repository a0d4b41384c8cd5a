"""``FreeTimeGaussians``: 4D Gaussians that live for a while and move freely.

Each Gaussian has a spatial mean μx, a temporal centre μt, a duration parameter d, a
velocity v, log-scales S, a quaternion R, an opacity logit o, SH colour coefficients and
a gate logit g̃ (docs/design.md §4). At time t it is an ordinary 3D Gaussian with

    μx(t) = μx + v (t − μt),     α(t) = sigmoid(o) · φ(t),
    φ(t)  = g + (1 − g) a(t)  (gate on)   or   a(t)  (gate off),
    a(t)  = exp(−½ ((t − μt) / s)²),   g = sigmoid(γ g̃),
    s     = max_duration / 6 · sigmoid(d)  (finite max_duration)  or  exp(d).

Every per-Gaussian tensor has leading dimension N and lives in ``params``. The class is the
first implementation of the method interface (``ftgspp/methods/base.py``); ``model.method=freetime``.
On the ``cpu`` backend it renders through a fused stage of its own (``prepare_cpu``:
``freetime_fused.py``, its time evaluation in Numba before the shared colour and projection).
"""

from __future__ import annotations

import math
from typing import ClassVar, Iterator

import numpy as np
import torch

from ftgspp.config import InitConfig, LossConfig, ModelConfig
from ftgspp.losses import gate_penalty, opacity_4d, scale_penalty
from ftgspp.methods.base import DynamicGaussians, GaussiansAt
from ftgspp.render.contract import CameraTensors, Projected

__all__ = ["FreeTimeGaussians", "GaussiansAt", "SH_C0", "duration_to_param"]

SH_C0 = 0.28209479177387814


class FreeTimeGaussians(DynamicGaussians):
    """Per-Gaussian parameters and their activations: FreeTimeGS, and FreeTimeGS++ with the
    bounded temporal scale and the gate (``ModelConfig``); the first ``DynamicGaussians``."""

    # the paper's rates (docs/design.md §4); LearningRates repeats them under these keys (lr.durations=...)
    LEARNING_RATES: ClassVar[dict[str, float]] = {"durations": 5e-3, "times": 1.6e-4, "velocities": 1.6e-3,
                                                  "gates": 1e-3}  # fmt: skip
    EXTENT_SCALED: ClassVar[tuple[str, ...]] = ("means", "velocities")
    DECAYING: ClassVar[tuple[str, ...]] = ("means", "velocities")

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

    def temporal_centres(self) -> torch.Tensor:
        """μt, ``[N]``."""
        return self.params["times"]

    def velocities_at(self, t: float) -> torch.Tensor:
        """v, the same at every time, ``[N, 3]``."""
        return self.params["velocities"]

    def frozen(self) -> set[str]:
        """The gate logits when the gate is switched off."""
        return set() if self.cfg.gate else {"gates"}

    def regularizers(self, g: GaussiansAt, weights: LossConfig) -> Iterator[tuple[str, float, torch.Tensor]]:
        """FreeTimeGS's 4D opacity and scale terms, and with the gate its penalty (docs/design.md §4)."""
        yield "opacity", weights.opacity_reg, opacity_4d(self.base_opacity(), g.temporal)
        yield "scale", weights.scale_reg, scale_penalty(self.params["scales"])
        if self.cfg.gate:
            yield "gate", weights.gate_reg, gate_penalty(self.gate())

    def at_time(self, t: float | torch.Tensor) -> GaussiansAt:
        """The 3D Gaussians at time ``t`` (seconds; a number or one time per Gaussian)."""
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

    def prepare_cpu(self, t: float, camera: CameraTensors, sh_degree: int) -> tuple[Projected, GaussiansAt] | None:
        """The fused stage (``freetime_fused.prepare``): exactly ``at_time``, SH colour and projection.
        None with ``model.fused_stage=false``, or for a subclass that redefines what the parameters mean
        at t (``_FUSED_FORMULAS``): the kernel knows only these formulas, so it renders through the
        generic path."""
        if self.cfg.fused_stage is False:
            return None
        if any(getattr(type(self), name) is not getattr(FreeTimeGaussians, name) for name in _FUSED_FORMULAS):
            return None
        from ftgspp.methods.freetime_fused import prepare  # Numba: imported on the first cpu render

        p, cfg = self.params, self.cfg
        prep = prepare(p, t, camera, sh_degree, cfg.max_duration, cfg.gate, cfg.gate_gamma)
        g = GaussiansAt(means=prep.means, quats=p["quats"], opacities=prep.opacities, temporal=prep.temporal,
                        log_scales=p["scales"], sh0=p["sh0"], shN=p["shN"])  # fmt: skip
        return prep.projected, g

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


# what the fused kernel computes itself: a subclass redefining one of these renders through at_time
_FUSED_FORMULAS = ("at_time", "temporal_opacity", "temporal_scale", "gate", "base_opacity")


def duration_to_param(duration: float, max_duration: float | None) -> float:
    """Inverse of the temporal-scale activation: the d that gives s = ``duration``."""
    if max_duration is None:
        return math.log(duration)
    frac = min(max(duration * 6.0 / max_duration, 1e-4), 1 - 1e-4)
    return math.log(frac / (1.0 - frac))
