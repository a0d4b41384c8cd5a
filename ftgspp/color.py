"""Per-camera affine colour correction, used during training only.

For training camera c the render I is mapped to ``I (I3 + ΔM_c) + b_c``; ΔM and b start
at zero (the identity), are switched on at ``cc_start_iter`` and are pulled back towards
the identity by ``loss.cc_reg · Σ(‖ΔM‖² + ‖b‖²)``. Evaluation renders never go through it.
"""

from __future__ import annotations

import torch
from torch import nn


class ColorCorrection(nn.Module):
    """One affine colour transform per training camera."""

    def __init__(self, n_cameras: int, device: torch.device | str = "cpu") -> None:
        super().__init__()
        self.delta = nn.Parameter(torch.zeros(n_cameras, 3, 3, device=device))  # [C, 3, 3] ΔM
        self.bias = nn.Parameter(torch.zeros(n_cameras, 3, device=device))  # [C, 3] b

    def forward(self, image: torch.Tensor, cam: int) -> torch.Tensor:
        """Apply camera ``cam``'s transform to ``image`` ``[H, W, 3]``."""
        return image + image @ self.delta[cam] + self.bias[cam]

    def regularizer(self) -> torch.Tensor:
        """Σ over cameras of ‖ΔM‖² + ‖b‖²."""
        return (self.delta**2).sum() + (self.bias**2).sum()

    def matrices(self) -> torch.Tensor:
        """The full 3x3 matrices I3 + ΔM, ``[C, 3, 3]``."""
        return torch.eye(3, device=self.delta.device) + self.delta.detach()
