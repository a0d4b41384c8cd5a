"""Which Gaussians to relocate and where (no tensors are changed here)."""

from __future__ import annotations

import math

import torch

POLICIES = ("mcmc", "exact_copy", "partial_copy")
MAX_COPIES = 51  # n is clamped to [1, 51] in the MCMC rule


def relocation_score(opacity: torch.Tensor, grad2d: torch.Tensor) -> torch.Tensor:
    """p = o/Σo + ‖∇2d‖/Σ‖∇2d‖ over the given (alive) Gaussians, normalised to sum 1, ``[M]``."""
    p = opacity / opacity.sum().clamp_min(1e-12)
    gsum = grad2d.sum()
    if gsum > 0:
        p = p + grad2d / gsum
    return p / p.sum()


def choose_relocation(
    opacity: torch.Tensor,  # [N] sigmoid(o)
    grad2d: torch.Tensor,  # [N] mean ‖∇ means2d‖ since the last relocation
    min_opacity: float,
    generator: torch.Generator,
    also_dead: torch.Tensor | None = None,  # [N] bool: dead by another rule (strategy.dead)
) -> tuple[torch.Tensor, torch.Tensor]:
    """Dead Gaussians (sigmoid(o) ≤ min_opacity, or ``also_dead``) and, for each, a source drawn
    with replacement from the others.

    Returns ``(dead [M], sources [M])`` as index tensors; both empty when nothing is dead
    or nothing is alive.
    """
    dead_mask = opacity <= min_opacity
    if also_dead is not None:
        dead_mask = dead_mask | also_dead.to(dead_mask.device)
    dead = dead_mask.nonzero(as_tuple=True)[0]
    alive = (~dead_mask).nonzero(as_tuple=True)[0]
    if len(dead) == 0 or len(alive) == 0:
        empty = torch.zeros(0, dtype=torch.long)
        return empty, empty
    p = relocation_score(opacity[alive], grad2d[alive])
    pick = torch.multinomial(p, len(dead), replacement=True, generator=generator)
    return dead, alive[pick]


MCMC_CLAMPS = ("after", "before")
DEAD_RULES = ("opacity", "clip_opacity")
MOMENT_RESETS = ("sources", "moved")  # whose Adam moments a relocation zeroes


def mcmc_opacity_scale(
    opacity: torch.Tensor,  # [M] source sigmoid(o)
    scale: torch.Tensor,  # [M, 3] source activated scales
    n: torch.Tensor,  # [M] number of Gaussians sharing the source after relocation (copies + 1)
    min_opacity: float,
    clamp: str = "after",
) -> tuple[torch.Tensor, torch.Tensor]:
    """The 3DGS-MCMC rule (Eq. 9): opacity and scale shared by n copies of one Gaussian.

    o_new = 1 − (1 − o)^(1/n) and s_new = o / D · s with
    D = Σ_{i=1..n} Σ_{k=0..i−1} C(i−1, k) (−1)^k / √(k+1) · o_new^(k+1).

    ``clamp`` says when o_new is clamped to [min_opacity, 1 − ε]: ``"after"`` computing D
    (gsplat 1.5.3, which the official FreeTimeGS++ code pins, so the paper's numbers; the
    default) or ``"before"`` (gsplat >= 1.6). They differ for faint sources: o = 0.006 split
    two ways gives a scale factor of 1.00 with "after" and 0.60 with "before".
    """
    if clamp not in MCMC_CLAMPS:
        raise ValueError(f"unknown MCMC clamp order '{clamp}' (choose from {', '.join(MCMC_CLAMPS)})")
    n = n.clamp(1, MAX_COPIES).to(opacity.dtype)
    eps = torch.finfo(torch.float32).eps
    o_new = 1.0 - (1.0 - opacity) ** (1.0 / n)
    if clamp == "before":
        o_new = o_new.clamp(min_opacity, 1.0 - eps)
    denom = torch.zeros_like(o_new)
    n_max = int(n.max().item()) if len(n) else 1
    for i in range(1, n_max + 1):
        active = n >= i
        for k in range(i):
            coef = math.comb(i - 1, k) * (-1) ** k / math.sqrt(k + 1)
            denom = denom + torch.where(active, coef * o_new ** (k + 1), torch.zeros_like(o_new))
    s_new = (opacity / denom)[:, None] * scale
    return o_new.clamp(min_opacity, 1.0 - eps), s_new
