"""Per-camera affine colour correction, used during training only.

For training camera c the render I is mapped to ``I (I3 + ΔM_c) + b_c``; ΔM and b start
at zero (the identity), are switched on at ``cc_start_iter`` and are pulled back towards
the identity by ``loss.cc_reg · Σ(‖ΔM‖² + ‖b‖²)``. Evaluation renders never go through it.

The transforms share a gauge: all of them may drift together while the scene's colours drift
the other way, and the training images do not notice — the uncorrected held-out camera does.
``gauge="mean_identity"`` removes that freedom: the transforms used are ΔM_c − mean ΔM and
b_c − mean b, so their mean is the identity by construction. ``mean_transform()`` reports the
mean (what a drift would show) for logging.
"""

from __future__ import annotations

import torch
from torch import nn


class ColorCorrection(nn.Module):
    """One affine colour transform per training camera."""

    GAUGES = ("free", "mean_identity")

    def __init__(self, n_cameras: int, device: torch.device | str = "cpu", gauge: str = "free") -> None:
        super().__init__()
        if gauge not in self.GAUGES:
            raise ValueError(f"unknown colour-correction gauge '{gauge}' (choose from {', '.join(self.GAUGES)})")
        self.gauge = gauge
        self.delta = nn.Parameter(torch.zeros(n_cameras, 3, 3, device=device))  # [C, 3, 3] ΔM
        self.bias = nn.Parameter(torch.zeros(n_cameras, 3, device=device))  # [C, 3] b

    def forward(self, image: torch.Tensor, cam: int) -> torch.Tensor:
        """Apply camera ``cam``'s transform to ``image`` ``[H, W, 3]``."""
        delta, bias = self._effective()
        return image + image @ delta[cam] + bias[cam]

    def _effective(self) -> tuple[torch.Tensor, torch.Tensor]:
        if self.gauge == "mean_identity":
            return self.delta - self.delta.mean(dim=0), self.bias - self.bias.mean(dim=0)
        return self.delta, self.bias

    def mean_transform(self) -> tuple[float, float]:
        """(‖mean ΔM‖_F, ‖mean b‖) of the transforms in use: 0 when they do not drift together."""
        delta, bias = self._effective()
        return float(delta.detach().mean(dim=0).norm()), float(bias.detach().mean(dim=0).norm())

    def regularizer(self) -> torch.Tensor:
        """Σ over cameras of ‖ΔM‖² + ‖b‖²."""
        return (self.delta**2).sum() + (self.bias**2).sum()

    def biases(self) -> torch.Tensor:
        """The biases in use, ``[C, 3]``."""
        return self._effective()[1].detach()

    def matrices(self) -> torch.Tensor:
        """The full 3x3 matrices I3 + ΔM, ``[C, 3, 3]``."""
        return torch.eye(3, device=self.delta.device) + self._effective()[0].detach()
