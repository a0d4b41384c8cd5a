"""The method interface: what a dynamic Gaussian method supplies to the trainer and the harness.

A method is a ``DynamicGaussians`` subclass. It owns its per-Gaussian parameters (one tensor
per name, leading dimension N, in ``self.params``) and says what they mean at a time t. The
renderer, colour correction, relocation, evaluation, diagnostics and the harness use only
what is written here; none of them reads a method's own parameters.

What every method supplies:

- ``from_points(...)``: its initial parameters from the initial point set (the same point
  clouds for every method: positions, colours, times, velocities, kNN spacing).
- ``at_time(t)``: the ordinary 3D Gaussians at time t (``GaussiansAt``; t a number or one time
  per Gaussian): positions,
  quaternions, log-scales, opacities, the temporal weight, and colour as SH coefficients or
  view-independent RGB.
- ``temporal_opacity(t)`` and ``temporal_centres()``: the temporal weight φ(t) in [0, 1]
  (the opacity is ``sigmoid(o) φ(t)``) and where it peaks; lifetimes, the clip-opacity
  relocation rule and the "drawn nowhere" count read them.
- ``lifetimes(θ)``: how long ``sigmoid(o) φ(t)`` stays at or above θ, seconds.
- ``velocities_at(t)``: d/dt of the positions (the motion diagnostics).
- ``regularizers(g, weights)``: the method's loss terms besides the photometric loss.
- Class attributes for the optimiser: the method's own learning rates (``LEARNING_RATES``, by
  key; the rates every method shares are ``LearningRates``'), which key each parameter's rate
  is under (``LR_KEYS``, default the parameter's name), which rates are multiplied by the
  scene extent (``EXTENT_SCALED``) and which decay over training (``DECAYING``);
  ``frozen()`` names parameters that are not optimised.
- Optionally ``prepare_cpu(t, camera, sh_degree)``: a fused stage of its own for the ``cpu``
  backend (time evaluation, colour and projection in Numba kernels, ``ftgspp.render.prepare``);
  without one, every backend renders ``at_time`` through the generic PyTorch projection.

What relocation copies (``ftgspp.strategy``): every parameter of a dead Gaussian is
overwritten by its source's; the MCMC rule then rewrites ``opacities`` and ``scales``. So
every method stores an opacity logit in ``params["opacities"]`` ``[N]`` and log-scales in
``params["scales"]`` ``[N, 3]``, besides ``params["means"]`` ``[N, 3]`` (its device is the
model's) and ``params["quats"]`` ``[N, 4]``. docs/methods.md is the guide to adding one.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar, Iterator

import numpy as np
import torch
from torch import nn

from ftgspp.config import InitConfig, LossConfig, ModelConfig
from ftgspp.render.contract import CameraTensors, Projected

REQUIRED = ("means", "quats", "scales", "opacities")  # the parameters the trainer itself touches


@dataclass
class GaussiansAt:
    """The 3D Gaussians of a model evaluated at one time.

    Colour is either SH coefficients (``sh0`` and ``shN``, evaluated along the viewing
    direction) or view-independent RGB (``colors``). ``scales`` (activated) and ``sh`` (DC and
    rest concatenated) are computed on first access, so renderers that do not need them pay
    nothing.
    """

    means: torch.Tensor  # [N, 3]
    quats: torch.Tensor  # [N, 4], any norm
    opacities: torch.Tensor  # [N] sigmoid(o) * phi(t)
    temporal: torch.Tensor  # [N] phi(t)
    log_scales: torch.Tensor  # [N, 3]
    sh0: torch.Tensor | None = None  # [N, 1, 3]
    shN: torch.Tensor | None = None  # [N, K - 1, 3]
    colors: torch.Tensor | None = None  # [N, 3] RGB, instead of SH

    @cached_property
    def scales(self) -> torch.Tensor:
        """Activated scales exp(S), ``[N, 3]``."""
        return torch.exp(self.log_scales)

    @cached_property
    def sh(self) -> torch.Tensor:
        """SH coefficients, ``[N, K, 3]``."""
        return torch.cat([self.sh0, self.shN], dim=1)


class DynamicGaussians(nn.Module):
    """Per-Gaussian parameters of one dynamic method and their meaning at a time t."""

    # the method's own rates by key (a parameter's name, or the key LR_KEYS maps it to), before
    # lr.scale; a LearningRates field of the same key, where there is one, is the option that sets
    # it, else +lr.method.<key>=<rate> (ftgspp.train_state.learning_rates)
    LEARNING_RATES: ClassVar[dict[str, float]] = {}
    LR_KEYS: ClassVar[dict[str, str]] = {}  # parameter -> the key of its rate, where the names differ
    EXTENT_SCALED: ClassVar[tuple[str, ...]] = ("means",)  # learning rate x scene extent
    DECAYING: ClassVar[tuple[str, ...]] = ("means",)  # rate decays to lr.means_final_ratio x over training

    def __init__(self, params: dict[str, torch.Tensor], cfg: ModelConfig) -> None:
        super().__init__()
        missing = [k for k in REQUIRED if k not in params]
        if missing:
            raise ValueError(f"{type(self).__name__} lacks the parameters {missing} every method has")
        self.cfg = cfg
        self.params = nn.ParameterDict({k: nn.Parameter(v.contiguous()) for k, v in params.items()})

    # --- construction -------------------------------------------------------------------
    @classmethod
    def from_points(
        cls,
        means: np.ndarray,  # [N, 3]
        colors: np.ndarray,  # [N, 3] RGB in [0, 1]
        times: np.ndarray,  # [N] seconds
        velocities: np.ndarray,  # [N, 3] (zero unless the initialisation estimates them)
        spacing: np.ndarray,  # [N] kNN spacing
        cfg: ModelConfig,
        init: InitConfig,
        device: torch.device | str = "cpu",
    ) -> "DynamicGaussians":
        """A model on ``device`` from the initial point set (``ftgspp.init``)."""
        raise NotImplementedError

    def __len__(self) -> int:
        return self.params["means"].shape[0]

    def subset(self, keep: torch.Tensor) -> "DynamicGaussians":
        """A detached copy with the Gaussians where ``keep [N]`` (bool) is True."""
        return type(self)({k: v.detach()[keep] for k, v in self.params.items()}, self.cfg)

    # --- what the trainer and the harness ask -------------------------------------------
    def at_time(self, t: float | torch.Tensor) -> GaussiansAt:
        """The 3D Gaussians at time ``t`` (seconds): a number, or one time per Gaussian ``[N]``."""
        raise NotImplementedError

    def temporal_opacity(self, t: float | torch.Tensor) -> torch.Tensor:
        """φ(t) in [0, 1], ``[N]`` (``t`` a number or one time per Gaussian)."""
        raise NotImplementedError

    def temporal_centres(self) -> torch.Tensor:
        """The time at which each Gaussian's φ peaks, ``[N]`` seconds."""
        raise NotImplementedError

    def lifetimes(self, threshold: float) -> torch.Tensor:
        """How long sigmoid(o)·φ(t) stays ≥ ``threshold``, seconds, ``[N]`` (``inf``: never fades)."""
        raise NotImplementedError

    def base_opacity(self) -> torch.Tensor:
        """sigmoid(o), ``[N]``."""
        return torch.sigmoid(self.params["opacities"])

    @torch.no_grad()
    def peak_opacity(self, t0: float, t1: float) -> torch.Tensor:
        """The largest opacity sigmoid(o)·φ(t) each Gaussian reaches for t in ``[t0, t1]``, ``[N]``:
        at its temporal centre clipped to the window (φ has one peak)."""
        t = self.temporal_centres().detach().clamp(t0, t1)
        return self.base_opacity() * self.temporal_opacity(t)

    def velocities_at(self, t: float) -> torch.Tensor:
        """d/dt of each Gaussian's position at time ``t``, ``[N, 3]`` (zero: a static method)."""
        return torch.zeros_like(self.params["means"])

    def regularizers(self, g: GaussiansAt, weights: LossConfig) -> Iterator[tuple[str, float, torch.Tensor]]:
        """The method's loss terms besides the photometric one, as (name, weight, value); the
        trainer adds ``weight × value`` to the loss in this order and logs each value."""
        return iter(())

    def frozen(self) -> set[str]:
        """Parameters left out of the optimiser."""
        return set()

    # --- optional: a fused stage on the cpu backend ---------------------------------------
    def prepare_cpu(self, t: float, camera: CameraTensors, sh_degree: int) -> tuple[Projected, GaussiansAt] | None:
        """The Gaussians at time ``t`` (seconds) projected into ``camera`` and coloured as the generic
        path colours them (SH of degree ``sh_degree`` along the viewing direction, or the method's
        RGB), by a fused stage of the method's own, and the ``GaussiansAt`` they came from. ``view.render_view`` asks on
        the ``cpu`` backend, for float32 parameters on the CPU; None (the default) renders
        ``at_time`` through the generic path (``render.project`` and autograd). A method's kernels
        evaluate its time formulas and hand each block of Gaussians to the shared colour and
        projection (``ftgspp.render.prepare``); their results must agree with the generic path to
        float32 rounding, gradients included (not bit for bit: the trainer records which path
        rendered a run, its param ``render_stage``)."""
        return None
