"""The rendering contract every backend implements, and the conventions they share.

``render()`` (``ftgspp.render``) projects 3D Gaussians with ``project.py`` (or the fused
``prepare.py`` node) and hands the 2D Gaussians to a backend's ``rasterize``:

```
rasterize(means2d [N,2], conics [N,3] (a, b, c) = upper triangle of the inverse 2D
          covariance (a = xx, b = xy, c = yy), colors [N,D], opacities [N] in [0,1],
          depths [N], radii [N,2] int (0 = culled), width, height, background [D] | None)
    -> image [H,W,D], alpha [H,W,1], depth [H,W,1]
```

- Pixel (row i, column j) has centre (x=j, y=i) in the same coordinates as ``means2d``
  (gsplat puts centres at half-integers: its coordinates are ours + ``PIXEL_OFFSET``).
- ``radii`` [N, 2] int, per axis (x, y); a Gaussian with either radius 0 is culled.
- Tiles ``TILE_SIZE`` x ``TILE_SIZE``. With x' = x + 0.5 (gsplat's coordinates), Gaussian k
  touches tiles tx in [tx0, tx1), ty in [ty0, ty1), computed in float32 as
  ``tx0 = clamp(floor(x'/16 - rx/16), 0, TX)``, ``tx1 = clamp(ceil(x'/16 + rx/16), 0, TX)``
  (same for y); a pixel only ever sees Gaussians whose tile range contains the pixel's tile.
- Per pixel, Gaussians in increasing depth (ties by index):
  power = -0.5(a dx^2 + c dy^2) - b dx dy with d = pixel - mean; skip if power > 0;
  alpha = min(ALPHA_MAX, o exp(power)); skip if alpha < ALPHA_MIN; T_next = T (1 - alpha);
  stop (without adding it) if T_next <= T_MIN; else add w = alpha T to colour and depth;
  T = T_next. Start T = 1.
- image = sum w c + T_final * background; alpha = 1 - T_final; depth = sum w z.

The projection (``project.py`` and the fused ``prepare_kernels``) follows gsplat's
``ProjectionEWA3DGSFused.cu``: culled (radii 0) if z < near_plane or z > FAR_PLANE, if
det(cov2d + eps2d I) <= 0, or if the opacity is below ALPHA_MIN; else
``extend = min(RADIUS_EXTEND, sqrt(2 ln(o / ALPHA_MIN)))`` (the distance in sigmas at which
alpha falls to 1/255), ``rx = ceil(extend sqrt(cov_xx))``, ``ry = ceil(extend sqrt(cov_yy))``,
culled when the box [x' - rx, x' + rx] x [y' - ry, y' + ry] misses the open image. The
Jacobian's tangents x/z and y/z are clamped to the image plus 30 % of the half field of view,
with gsplat's principal point (cx + 0.5, cy + 0.5).

These are gsplat 1.5.3's CUDA conventions (read from its sources), so the ``reference``,
``cpu`` and ``gsplat`` backends train the same model; ``tests/render/test_gsplat_parity.py``
runs gsplat's own Python code against ``reference``. Every backend imports its constants
from here (never from the package ``__init__``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import torch

# gsplat 1.5.3's conventions, shared by every backend (see the module docstring).
TILE_SIZE = 16
ALPHA_MAX = 0.999  # RasterizeToPixels3DGSFwd.cu: min(0.999f, opac * exp(-sigma))
ALPHA_MIN = 1.0 / 255.0  # ALPHA_THRESHOLD
T_MIN = 1e-4  # a pixel stops at the first Gaussian whose T_next <= T_MIN
EPS2D = 0.3  # low-pass added to the 2D covariance, in pixels^2
RADIUS_EXTEND = 3.33  # largest radius, in standard deviations of each axis
FAR_PLANE = 1e10
PIXEL_OFFSET = 0.5  # gsplat's pixel coordinates minus ours


@dataclass
class RenderOutput:
    """What a backend returns. ``means2d`` keeps its gradient after backward (relocation score)."""

    image: torch.Tensor  # [H, W, D] composited colours (+ background * (1 - alpha))
    alpha: torch.Tensor  # [H, W, 1] accumulated opacity
    depth: torch.Tensor  # [H, W, 1] alpha-weighted camera-space depth (not normalised)
    means2d: torch.Tensor  # [N, 2] projected centres in pixels; .grad set after backward
    radii: torch.Tensor  # [N, 2] integer pixel radius per axis (x, y), 0 = culled
    depths: torch.Tensor  # [N] camera-space depth of each centre
    # how the Gaussians were evaluated and projected: "generic" (at_time, render.project) or "fused"
    # (the method's fused cpu stage, render.prepare); the trainer records it with the run
    stage: str = "generic"


@dataclass(frozen=True)
class CameraTensors:
    """One camera as the renderers take it: float32 tensors on the model's device."""

    viewmat: torch.Tensor  # [4, 4] world-to-camera
    K: torch.Tensor  # [3, 3] OpenCV intrinsics (pixel centres at integers)
    centre: torch.Tensor  # [3] camera centre (world)
    width: int
    height: int


class Projected(NamedTuple):
    """Gaussians projected into one camera: what a backend's ``rasterize`` takes besides the image size."""

    means2d: torch.Tensor  # [N, 2] pixels (zeros where culled)
    conics: torch.Tensor  # [N, 3] upper triangle of the inverse 2D covariance (zeros where culled)
    colors: torch.Tensor  # [N, D]
    opacities: torch.Tensor  # [N] in [0, 1]
    depths: torch.Tensor  # [N] camera-space z of the centres
    radii: torch.Tensor  # [N, 2] int pixel radius per axis, 0 = culled


# The signature every backend's ``rasterize`` has (see the module docstring).
Rasterize = Callable[..., "tuple[torch.Tensor, torch.Tensor, torch.Tensor]"]
