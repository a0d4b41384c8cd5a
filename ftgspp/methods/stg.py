"""``SpacetimeGaussians``: Spacetime Gaussians (Li et al., CVPR 2024), the "lite" variant.

Each Gaussian has a spatial centre μ, a temporal centre μτ, a temporal scale parameter
s̃, cubic motion coefficients b1, b2, b3, a quaternion q and its angular velocity ω,
log-scales S, an opacity logit o and an RGB colour c. With Δt = t − μτ:

    μ(t) = μ + b1 Δt + b2 Δt² + b3 Δt³,     q(t) = q + ω Δt  (normalised by the renderer),
    α(t) = sigmoid(o) · φ(t),               φ(t) = exp(−(Δt / exp(s̃))²)   (temporal RBF).

Initialisation follows the public code's lite model: every initial point becomes one
Gaussian at its own time (μτ), s̃ = 0, no motion or rotation speed, opacity 0.1, scales the
spacing it is given (log clamped to [−10, 1]), colour the point's RGB. The public code takes that
spacing over the points of every frame of the clip together, as the root mean square distance to
the 3 nearest (squared, floored at 1e-7): ``model.init_spacing=union``, over every keyframe's
points here (ftgspp/init/spacing.py); conf/model/stg.yaml sets it. At null it is the per-keyframe
mean distance instead (STGS's runs before issue 59 started from it): a static surface seen at several
keyframes then starts about as large as a keyframe's point spacing, not as small as its sightings
agree.

Left out, and why: the full model's spacetime features and MLP colour decoder (the lite
variant renders RGB, which the issue and a CPU budget ask for); its densification, pruning,
opacity resets and guided sampling of new Gaussians (every method here trains at a fixed
budget under the harness's relocation, so methods are compared at equal size); the temporal
opacity's learning-rate decay of μτ (held constant) and the renderer's batch of two views per
step. Time is in seconds; the public code's is normalised to the clip, the same for the 1-s
clips the quick profile trains on. Colour is composited as given, without clamping, as there.
On the ``cpu`` backend it renders through a fused stage of its own (``prepare_cpu``:
``stg_fused.py``, its time evaluation in Numba before the shared projection).
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
import torch

from ftgspp.config import InitConfig, ModelConfig
from ftgspp.errors import InputError
from ftgspp.methods.base import DynamicGaussians, GaussiansAt
from ftgspp.render.contract import CameraTensors, Projected

INIT_OPACITY = 0.1
INIT_LOG_TIME_SCALE = 0.0  # exp(0) = 1 s


class SpacetimeGaussians(DynamicGaussians):
    """Temporal-RBF opacity, cubic motion and linear rotation around each Gaussian's own time."""

    # the public code's rates: temporal centre and log temporal scale, cubic motion (x scene extent: its
    # position rate x 0.5 x 3.5) and rotation speed; LearningRates repeats them under these keys (lr.motion=...)
    LEARNING_RATES: ClassVar[dict[str, float]] = {"trbf_center": 1e-4, "trbf_scale": 0.03, "motion": 2.8e-4,
                                                  "omega": 1e-4}  # fmt: skip
    LR_KEYS: ClassVar[dict[str, str]] = {"rgb": "sh0"}  # the colour's rate is the SH DC rate (2.5e-3, as there)
    EXTENT_SCALED: ClassVar[tuple[str, ...]] = ("means", "motion")
    DECAYING: ClassVar[tuple[str, ...]] = ("means",)

    def __init__(self, params: dict[str, torch.Tensor], cfg: ModelConfig) -> None:
        if cfg.sh_degree != 0:
            raise InputError("model.sh_degree", f"Spacetime Gaussians (lite) render RGB: sh_degree must be 0,"
                             f" not {cfg.sh_degree}")
        super().__init__(params, cfg)

    @classmethod
    def from_points(cls, means: np.ndarray, colors: np.ndarray, times: np.ndarray, velocities: np.ndarray,
                    spacing: np.ndarray, cfg: ModelConfig, init: InitConfig,
                    device: torch.device | str = "cpu") -> "SpacetimeGaussians":
        """One Gaussian per initial point, as the public lite model starts (module docstring);
        ``velocities`` and the FreeTimeGS-specific ``init`` settings are not used."""
        n = len(means)
        f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
        log_spacing = torch.log(f32(spacing).clamp_min(1e-7)).clamp(-10.0, 1.0)
        params = {
            "means": f32(means),
            "trbf_center": f32(times),
            "trbf_scale": torch.full((n,), INIT_LOG_TIME_SCALE, device=device),
            "motion": torch.zeros(n, 9, device=device),  # [b1 | b2 | b3], xyz each
            "quats": f32([1.0, 0.0, 0.0, 0.0]).repeat(n, 1),
            "omega": torch.zeros(n, 4, device=device),
            "scales": log_spacing[:, None].repeat(1, 3),
            "opacities": torch.full((n,), math.log(INIT_OPACITY / (1 - INIT_OPACITY)), device=device),
            "rgb": f32(colors),
        }
        return cls(params, cfg)

    def _dt(self, t: float | torch.Tensor) -> torch.Tensor:
        return t - self.params["trbf_center"]

    def temporal_centres(self) -> torch.Tensor:
        return self.params["trbf_center"]

    def temporal_opacity(self, t: float | torch.Tensor) -> torch.Tensor:
        return torch.exp(-((self._dt(t) / torch.exp(self.params["trbf_scale"])) ** 2))

    def at_time(self, t: float | torch.Tensor) -> GaussiansAt:
        p = self.params
        dt = self._dt(t)[:, None]  # [N, 1]
        m = p["motion"]
        means = p["means"] + m[:, 0:3] * dt + m[:, 3:6] * dt**2 + m[:, 6:9] * dt**3
        phi = self.temporal_opacity(t)
        return GaussiansAt(means=means, quats=p["quats"] + p["omega"] * dt, opacities=self.base_opacity() * phi,
                           temporal=phi, log_scales=p["scales"], colors=p["rgb"])

    def velocities_at(self, t: float) -> torch.Tensor:
        dt = self._dt(t)[:, None]
        m = self.params["motion"]
        return m[:, 0:3] + 2.0 * m[:, 3:6] * dt + 3.0 * m[:, 6:9] * dt**2

    def prepare_cpu(self, t: float, camera: CameraTensors, sh_degree: int) -> tuple[Projected, GaussiansAt] | None:
        """The fused stage (``stg_fused.prepare``): exactly ``at_time`` and the projection, colour the
        RGB as given (``sh_degree`` does not apply). None for a subclass that redefines what the
        parameters mean at t (``_FUSED_FORMULAS``): the kernel knows only these formulas, so it
        renders through the generic path. Only with ``model.fused_stage=true`` (conf/model/stg.yaml):
        STGS's runs before this stage went through the generic path, and a run keeps its bits."""
        if not self.cfg.fused_stage:
            return None
        if any(getattr(type(self), name) is not getattr(SpacetimeGaussians, name) for name in _FUSED_FORMULAS):
            return None
        from ftgspp.methods.stg_fused import prepare  # Numba: imported on the first cpu render

        p = self.params
        prep = prepare(p, t, camera)
        # quat(t) is the projection's business inside the kernel; this one is for the caller, as at_time's
        g = GaussiansAt(means=prep.means, quats=p["quats"] + p["omega"] * self._dt(t)[:, None],
                        opacities=prep.opacities, temporal=prep.temporal, log_scales=p["scales"],
                        colors=p["rgb"])  # fmt: skip
        return prep.projected, g

    def lifetimes(self, threshold: float) -> torch.Tensor:
        """sigmoid(o) exp(−(Δt/s)²) ≥ θ for |Δt| ≤ s √log(o/θ): Δt(θ) = 2 s √log(o/θ), 0 when o ≤ θ."""
        ratio = torch.clamp(self.base_opacity() / threshold, min=1.0)
        return 2.0 * torch.exp(self.params["trbf_scale"]) * torch.sqrt(torch.log(ratio))


# what the fused kernel computes itself: a subclass redefining one of these renders through at_time
_FUSED_FORMULAS = ("at_time", "temporal_opacity", "_dt", "base_opacity")
