"""Every call into gsplat (the optional ``cuda`` extra), under this project's conventions.

- ``render``: ``gsplat.rasterization`` (its own CUDA projection, same EWA conventions, eps2d
  0.3) behind ``ftgspp.render.render(..., backend="gsplat")``, returning a ``RenderOutput``.
- ``rasterize``: gsplat's 2D tile rasterizer under the contract signature of ``contract.py``
  (projected Gaussians in, image / alpha / depth out), timed by ``ftgspp bench render``.

gsplat puts pixel centres at half-integers and ours sit at integers, so both shift by
+0.5 px on the way in. gsplat is imported when a function is called, never when this module
is: it is absent on CPU machines. Whether gsplat may be used (installed, CUDA tensors) is
decided in one place, ``ftgspp.render.resolve_backend``; these functions take the tensors
they are given. Not exercised where no GPU is available.
"""

from __future__ import annotations

from types import ModuleType

import torch

from ftgspp.render.contract import EPS2D, TILE_SIZE, RenderOutput


def _gsplat() -> ModuleType:
    """The ``gsplat`` module; a RuntimeError naming the backend if it cannot be imported."""
    try:
        import gsplat
    except ImportError as err:
        raise RuntimeError(f"render backend 'gsplat' is unavailable: {err}") from err
    return gsplat


def render(
    means: torch.Tensor,  # [N, 3] world
    quats: torch.Tensor,  # [N, 4] (w, x, y, z), any norm
    scales: torch.Tensor,  # [N, 3] activated
    opacities: torch.Tensor,  # [N] in [0, 1]
    colors: torch.Tensor,  # [N, D]
    viewmat: torch.Tensor,  # [4, 4] world-to-camera
    K: torch.Tensor,  # [3, 3] OpenCV intrinsics (pixel centres at integers)
    width: int,
    height: int,
    background: torch.Tensor | None,  # [D]
    near_plane: float,
) -> RenderOutput:
    """3D Gaussians through ``gsplat.rasterization`` (projection and rasterization on CUDA).

    The principal point is shifted by +0.5 for gsplat, so the returned ``means2d`` (gsplat's
    own, kept for their gradient) are offset by +0.5 px from ``project``'s.
    """
    gsplat = _gsplat()
    K_gs = K.clone()
    K_gs[0, 2] += 0.5
    K_gs[1, 2] += 0.5
    bg = None if background is None else background.reshape(1, -1)
    rgbd, alpha, meta = gsplat.rasterization(
        means, quats, scales, opacities, colors, viewmat[None], K_gs[None], width, height,
        near_plane=near_plane, eps2d=EPS2D, tile_size=TILE_SIZE, render_mode="RGB+D",
        backgrounds=bg, packed=False,
    )  # fmt: skip
    batched = meta["means2d"]  # [1, N, 2]
    means2d = batched[0]  # [N, 2]; not itself in the graph, so its grad is copied in by a hook
    if batched.requires_grad:
        means2d.retain_grad()
        batched.register_hook(lambda grad: setattr(means2d, "grad", grad[0]))
    radii = meta["radii"][0]
    if radii.dim() == 2:  # gsplat >= 1.5 returns per-axis radii
        radii = radii.max(dim=-1).values
    return RenderOutput(rgbd[0, ..., :-1], alpha[0], rgbd[0, ..., -1:], means2d, radii, meta["depths"][0])


def rasterize(
    means2d: torch.Tensor,  # [N, 2]
    conics: torch.Tensor,  # [N, 3]
    colors: torch.Tensor,  # [N, D]
    opacities: torch.Tensor,  # [N]
    depths: torch.Tensor,  # [N]
    radii: torch.Tensor,  # [N] int, 0 = culled
    width: int,
    height: int,
    background: torch.Tensor | None = None,  # [D]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The contract's ``rasterize`` on gsplat's 2D tile kernels: image [H, W, D], alpha and
    depth [H, W, 1]. Depth is composited as one more colour channel."""
    gsplat = _gsplat()
    m2d = (means2d + 0.5).unsqueeze(0)  # [1, N, 2]
    rad = radii.int()
    tiles_w, tiles_h = -(-width // TILE_SIZE), -(-height // TILE_SIZE)
    try:
        _, isect_ids, flatten_ids = gsplat.isect_tiles(m2d, rad.unsqueeze(0), depths.unsqueeze(0), TILE_SIZE,
                                                       tiles_w, tiles_h)  # fmt: skip
    except (RuntimeError, TypeError):  # gsplat >= 1.5 wants per-axis radii [C, N, 2]
        rad2 = torch.stack([rad, rad], -1).unsqueeze(0)
        _, isect_ids, flatten_ids = gsplat.isect_tiles(m2d, rad2, depths.unsqueeze(0), TILE_SIZE, tiles_w, tiles_h)
    offsets = gsplat.isect_offset_encode(isect_ids, 1, tiles_w, tiles_h)
    feats = torch.cat([colors, depths.unsqueeze(-1)], -1).unsqueeze(0)  # [1, N, D + 1]
    bg = None
    if background is not None:
        bg = torch.cat([background, background.new_zeros(1)]).unsqueeze(0)
    out, alpha = gsplat.rasterize_to_pixels(m2d, conics.unsqueeze(0), feats, opacities.unsqueeze(0),
                                            width, height, TILE_SIZE, offsets, flatten_ids, backgrounds=bg)  # fmt: skip
    return out[0, ..., :-1], alpha[0], out[0, ..., -1:]
