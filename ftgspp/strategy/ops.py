"""In-place changes to Gaussian parameters that keep the optimizer moments in sync."""

from __future__ import annotations

import torch
from torch import nn


@torch.no_grad()
def reset_moments(optimizer: torch.optim.Optimizer, params: nn.ParameterDict, idx: torch.Tensor) -> None:
    """Zero the Adam moments of Gaussians ``idx`` (rows of every per-Gaussian parameter)."""
    for p in params.values():
        state = optimizer.state.get(p, {})
        for key in ("exp_avg", "exp_avg_sq"):
            if key in state:
                state[key][idx] = 0


@torch.no_grad()
def copy_gaussians(
    params: nn.ParameterDict,
    dead: torch.Tensor,  # [M]
    sources: torch.Tensor,  # [M]
    keep: tuple[str, ...] = (),
) -> None:
    """Overwrite Gaussians ``dead`` with ``sources`` for every parameter not in ``keep``."""
    for name, p in params.items():
        if name not in keep:
            p.data[dead] = p.data[sources]
