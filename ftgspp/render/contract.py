"""The rendering contract every backend implements, and the conventions they share.

``render()`` (``ftgspp.render``) projects 3D Gaussians with ``project.py`` (or the fused
``prepare.py`` node) and hands the 2D Gaussians to a backend's ``rasterize``:

```
rasterize(means2d [N,2], conics [N,3] (a, b, c) = upper triangle of the inverse 2D
          covariance (a = xx, b = xy, c = yy), colors [N,D], opacities [N] in [0,1],
          depths [N], radii [N] int (0 = culled), width, height, background [D] | None)
    -> image [H,W,D], alpha [H,W,1], depth [H,W,1]
```

- Pixel (row i, column j) has centre (x=j, y=i) in the same coordinates as ``means2d``.
- Tiles ``TILE_SIZE`` x ``TILE_SIZE``. Gaussian k touches tiles tx in [tx0, tx1), ty in
  [ty0, ty1) with ``tx0 = clamp(floor((x - r) / 16), 0, TX)``,
  ``tx1 = clamp(floor((x + r + 15) / 16), 0, TX)`` (same for y), r = radii[k]; a pixel only
  ever sees Gaussians whose tile range contains the pixel's tile.
- Per pixel, Gaussians in increasing depth (ties by index):
  power = -0.5(a dx^2 + c dy^2) - b dx dy with d = pixel - mean; skip if power > 0;
  alpha = min(ALPHA_MAX, o exp(power)); skip if alpha < ALPHA_MIN; T_next = T (1 - alpha);
  stop (without adding it) if T_next < T_MIN; else add w = alpha T to colour and depth;
  T = T_next. Start T = 1.
- image = sum w c + T_final * background; alpha = 1 - T_final; depth = sum w z.

Every backend imports its constants from here (never from the package ``__init__``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

# Compositing conventions of 3DGS, shared by every backend.
TILE_SIZE = 16
ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1e-4
EPS2D = 0.3  # low-pass added to the 2D covariance, in pixels^2


@dataclass
class RenderOutput:
    """What a backend returns. ``means2d`` keeps its gradient after backward (relocation score)."""

    image: torch.Tensor  # [H, W, D] composited colours (+ background * (1 - alpha))
    alpha: torch.Tensor  # [H, W, 1] accumulated opacity
    depth: torch.Tensor  # [H, W, 1] alpha-weighted camera-space depth (not normalised)
    means2d: torch.Tensor  # [N, 2] projected centres in pixels; .grad set after backward
    radii: torch.Tensor  # [N] integer pixel radius, 0 = culled
    depths: torch.Tensor  # [N] camera-space depth of each centre


# The signature every backend's ``rasterize`` has (see the module docstring).
Rasterize = Callable[..., "tuple[torch.Tensor, torch.Tensor, torch.Tensor]"]
