"""Training losses: photometric term and regularisers (pure functions).

total = (1 − λ)·L1 + λ·(1 − SSIM) + 0.01·mean(sigmoid(o)·φ(t).detach())
        + 0.01·mean(exp(S)) [+ 1e-3·mean(1 − g)] [+ CC term]   (docs/design.md §4)
"""

from __future__ import annotations

import numpy as np
import torch

from ftgspp.image_metrics import ssim_same


def photometric(pred: torch.Tensor, gt: torch.Tensor, ssim_weight: float) -> tuple[torch.Tensor, torch.Tensor]:
    """``((1 − λ) L1 + λ (1 − SSIM), L1)`` for images ``[H, W, 3]`` in [0, 1]."""
    l1 = (pred - gt).abs().mean()
    if ssim_weight == 0:
        return l1, l1
    return (1.0 - ssim_weight) * l1 + ssim_weight * (1.0 - ssim_same(pred, gt)), l1


def logged_photometric(pred: torch.Tensor, gt: torch.Tensor) -> tuple[float, float]:
    """``(L1, MSE)`` of a training view for the logs, summed in float64 by numpy in a fixed order.

    Torch splits large reductions between its threads, so ``.mean().item()`` can change in the
    last bit with the thread count (``NUMBA_NUM_THREADS`` caps both); these values do not, so
    logged curves compare bit for bit across machines with different core counts.
    """
    d = (pred.detach() - gt.detach()).to("cpu", torch.float64).numpy()
    return float(np.abs(d).mean()), float(np.square(d).mean())


def opacity_4d(base_opacity: torch.Tensor, temporal: torch.Tensor) -> torch.Tensor:
    """FreeTimeGS 4D regulariser: mean(sigmoid(o) · φ(t).detach())."""
    return (base_opacity * temporal.detach()).mean()


def scale_penalty(log_scales: torch.Tensor) -> torch.Tensor:
    """mean(exp(S)) over all Gaussians and axes."""
    return torch.exp(log_scales).mean()


def gate_penalty(gate: torch.Tensor) -> torch.Tensor:
    """mean(1 − g): pushes Gaussians to be persistent unless the data says otherwise."""
    return (1.0 - gate).mean()
