"""Every call into gsplat 1.5.3 (the optional ``cuda`` extra), under this project's conventions.

- ``render``: ``gsplat.rasterization`` (its own fused projection and tile rasterizer) behind
  ``ftgspp.render.render(..., backend="gsplat")``, returning a ``RenderOutput``.
- ``rasterize``: gsplat's 2D tile rasterizer under the contract signature of ``contract.py``
  (projected Gaussians in, image / alpha / depth out), timed by ``ftgspp bench render``.

gsplat puts pixel centres at half-integers and ours sit at integers, so positions shift by
``PIXEL_OFFSET`` on the way in and out. For the Gaussians gsplat culls, its ``means2d``,
``depths`` and ``conics`` are left uninitialised (``at::empty``): ``render`` returns zeros for
them (and the camera-space depth of every centre, as ``project`` does). gsplat is imported
when a function is called, never when this module is: it is absent on most CPU machines.
Whether gsplat may be used (installed, CUDA tensors) is decided in one place,
``ftgspp.render.resolve_backend``; these functions take the tensors they are given, so the
test suite drives them with CPU tensors through gsplat's own Python code, its CUDA ops
replaced by torch stand-ins (``tests/render/gsplat_standins.py``).
"""

from __future__ import annotations

from types import ModuleType

import torch

from ftgspp.render.contract import EPS2D, FAR_PLANE, PIXEL_OFFSET, TILE_SIZE, RenderOutput


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
    """3D Gaussians through ``gsplat.rasterization`` (projection and rasterization by gsplat).

    ``means2d`` are in this project's pixel coordinates, zero where culled; after backward their
    ``.grad`` holds gsplat's screen-space gradient (the relocation score).
    """
    gsplat = _gsplat()
    K_gs = K.clone()
    K_gs[0, 2] += PIXEL_OFFSET
    K_gs[1, 2] += PIXEL_OFFSET
    bg = None if background is None else background.reshape(1, -1)
    rgbd, alpha, meta = gsplat.rasterization(
        means, quats, scales, opacities, colors, viewmat[None], K_gs[None], width, height,
        near_plane=near_plane, far_plane=FAR_PLANE, eps2d=EPS2D, tile_size=TILE_SIZE, render_mode="RGB+D",
        backgrounds=bg, packed=False,
    )  # fmt: skip
    radii = meta["radii"][0]  # [N, 2] int32
    visible = (radii > 0).all(dim=-1, keepdim=True)  # [N, 1]
    batched = meta["means2d"]  # [1, N, 2], gsplat's coordinates; garbage where culled
    means2d = torch.where(visible, batched[0].detach() - PIXEL_OFFSET, 0.0)  # [N, 2]
    if batched.requires_grad:  # not itself in the graph: its grad is copied in by a hook
        means2d.requires_grad_(True)
        means2d.retain_grad()
        batched.register_hook(lambda grad: setattr(means2d, "grad", torch.where(visible, grad[0], 0.0)))
    depths = means @ viewmat[2, :3] + viewmat[2, 3]  # [N] camera-space z, as project() returns
    radii = torch.where(visible, radii, 0)
    return RenderOutput(rgbd[0, ..., :-1], alpha[0], rgbd[0, ..., -1:], means2d, radii, depths)


def rasterize(
    means2d: torch.Tensor,  # [N, 2]
    conics: torch.Tensor,  # [N, 3]
    colors: torch.Tensor,  # [N, D]
    opacities: torch.Tensor,  # [N]
    depths: torch.Tensor,  # [N]
    radii: torch.Tensor,  # [N, 2] int, 0 = culled
    width: int,
    height: int,
    background: torch.Tensor | None = None,  # [D]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The contract's ``rasterize`` on gsplat's 2D tile kernels: image [H, W, D], alpha and
    depth [H, W, 1]. Depth is composited as one more colour channel."""
    gsplat = _gsplat()
    m2d = (means2d + PIXEL_OFFSET).unsqueeze(0)  # [1, N, 2]
    tiles_w, tiles_h = -(-width // TILE_SIZE), -(-height // TILE_SIZE)
    _, isect_ids, flatten_ids = gsplat.isect_tiles(m2d, radii.int().unsqueeze(0), depths.unsqueeze(0), TILE_SIZE,
                                                   tiles_w, tiles_h)  # fmt: skip
    offsets = gsplat.isect_offset_encode(isect_ids, 1, tiles_w, tiles_h)
    feats = torch.cat([colors, depths.unsqueeze(-1)], -1).unsqueeze(0)  # [1, N, D + 1]
    bg = None
    if background is not None:
        bg = torch.cat([background, background.new_zeros(1)]).unsqueeze(0)
    out, alpha = gsplat.rasterize_to_pixels(m2d, conics.unsqueeze(0), feats, opacities.unsqueeze(0),
                                            width, height, TILE_SIZE, offsets, flatten_ids, backgrounds=bg)  # fmt: skip
    return out[0, ..., :-1], alpha[0], out[0, ..., -1:]
