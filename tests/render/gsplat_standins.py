"""Torch stand-ins for gsplat 1.5.3's CUDA ops, so that gsplat's own Python code runs on CPU.

gsplat calls its CUDA extension through ``gsplat.cuda._backend._C`` (compiled on first use)
and, in its pure-torch rasterizer, through nerfacc. ``install(monkeypatch)`` puts a module
with these stand-ins in place of both, so ``gsplat.rasterization``, ``isect_tiles``,
``rasterize_to_pixels`` and ``strategy.ops.relocate`` run unchanged on CPU tensors. Nothing is
ever compiled.

Each stand-in follows the conventions of the CUDA kernel it replaces (read from the 1.5.3
sources, ``gsplat/cuda/csrc``), written here in torch, not copied:

- ``projection_ewa_3dgs_fused_fwd`` (``ProjectionEWA3DGSFused.cu``): camera-space centre,
  covariance from the normalised quaternion and scales, the Jacobian with x/z and y/z clamped
  to the image plus 30 % of the half field of view, eps2d on the diagonal, the per-axis,
  opacity-aware radius, culling. Culled entries of means2d / depths / conics are NaN: the
  kernel leaves them uninitialised (``at::empty``), and NaN makes any use of them visible.
- ``intersect_tile`` / ``intersect_offset``: gsplat's own torch versions
  (``_torch_impl._isect_tiles`` / ``_isect_offset_encode``), whose rules match
  ``IntersectTile.cu``.
- ``rasterize_to_pixels_3dgs_fwd``: gsplat's own ``_torch_impl._rasterize_to_pixels``, which
  needs ``rasterize_to_indices_3dgs`` (``RasterizeToIndices3DGS.cu``: per pixel, front to
  back, skip sigma < 0 or alpha < 1/255, stop before the Gaussian whose T_next <= 1e-4) and
  nerfacc's ``render_weight_from_alpha`` / ``accumulate_along_rays`` (weights alpha T).
- The backward ops are the vector-Jacobian products of those forwards (autograd), with the
  CUDA kernels' rule that culled Gaussians receive no gradient.
- ``relocation`` (``RelocationCUDA.cu``): the 3DGS-MCMC opacity and scale of Eq. 9.
"""

from __future__ import annotations

import math
import sys
import types

import pytest
import torch
from torch import Tensor

ALPHA_THRESHOLD = 1.0 / 255.0


# ------------------------------------------------------------------------------ projection


def _project(means, quats, scales, opacities, viewmats, Ks, width, height, eps2d, near, far, radius_clip, keep=None):
    """Fused projection of N Gaussians into C cameras, finite everywhere (culled rows included).

    ``keep`` [C, N] replaces the depth test (the backward knows validity from the radii only).
    Returns (radii [C, N, 2] int32, means2d [C, N, 2], depths [C, N], conics [C, N, 3],
    valid [C, N])."""
    R = viewmats[:, :3, :3]  # [C, 3, 3]
    p = torch.einsum("cij,nj->cni", R, means) + viewmats[:, None, :3, 3]  # [C, N, 3]
    x, y, z = p.unbind(-1)
    in_range = (z >= near) & (z <= far) if keep is None else keep
    zs = torch.where(in_range, z, torch.ones_like(z))
    q = quats / quats.norm(dim=-1, keepdim=True)
    w_, qx, qy, qz = q.unbind(-1)
    rot = torch.stack([
        1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - w_ * qz), 2 * (qx * qz + w_ * qy),
        2 * (qx * qy + w_ * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - w_ * qx),
        2 * (qx * qz - w_ * qy), 2 * (qy * qz + w_ * qx), 1 - 2 * (qx * qx + qy * qy),
    ], -1).reshape(-1, 3, 3)  # fmt: skip
    m = rot * scales[:, None, :]
    cov_w = m @ m.transpose(-1, -2)  # [N, 3, 3]
    cov_c = R[:, None] @ cov_w[None] @ R[:, None].transpose(-1, -2)  # [C, N, 3, 3]
    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]  # [C, 1]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    lim_xp, lim_xn = (width - cx) / fx + 0.3 * tan_x, cx / fx + 0.3 * tan_x
    lim_yp, lim_yn = (height - cy) / fy + 0.3 * tan_y, cy / fy + 0.3 * tan_y
    rz = 1.0 / zs
    tx = zs * torch.minimum(lim_xp, torch.maximum(-lim_xn, x * rz))
    ty = zs * torch.minimum(lim_yp, torch.maximum(-lim_yn, y * rz))
    zero = torch.zeros_like(zs)
    J = torch.stack([
        torch.stack([fx * rz, zero, -fx * tx * rz * rz], -1),
        torch.stack([zero, fy * rz, -fy * ty * rz * rz], -1),
    ], -2)  # [C, N, 2, 3]  fmt: skip
    cov2d = J @ cov_c @ J.transpose(-1, -2)  # [C, N, 2, 2]
    mean2d = torch.stack([fx * x * rz + cx, fy * y * rz + cy], -1)
    a, b, c = cov2d[..., 0, 0] + eps2d, cov2d[..., 0, 1], cov2d[..., 1, 1] + eps2d
    det = a * c - b * b
    valid = in_range & (det > 0)
    det_s = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det_s, -b / det_s, a / det_s], -1)
    with torch.no_grad():
        extend = torch.full_like(a, 3.33)
        if opacities is not None:
            o = opacities.detach().expand_as(a)
            valid = valid & (o >= ALPHA_THRESHOLD)
            ratio = torch.where(o >= ALPHA_THRESHOLD, o / ALPHA_THRESHOLD, torch.ones_like(o))
            extend = torch.minimum(extend, torch.sqrt(2.0 * torch.log(ratio)))
        rx = torch.ceil(extend * torch.sqrt(a.clamp_min(0)))
        ry = torch.ceil(extend * torch.sqrt(c.clamp_min(0)))
        valid = valid & ~((rx <= radius_clip) & (ry <= radius_clip))
        mx, my = mean2d.detach().unbind(-1)
        valid = valid & ~((mx + rx <= 0) | (mx - rx >= width) | (my + ry <= 0) | (my - ry >= height))
        radii = torch.where(valid[..., None], torch.stack([rx, ry], -1), 0).to(torch.int32)
    return radii, mean2d, z, conics, valid


def projection_ewa_3dgs_fused_fwd(means, covars, quats, scales, opacities, viewmats, Ks, width, height, eps2d,
                                  near_plane, far_plane, radius_clip, calc_compensations, camera_model):  # fmt: skip
    assert covars is None and means.dim() == 2 and camera_model == "pinhole" and not calc_compensations
    radii, means2d, depths, conics, valid = _project(means, quats, scales, opacities, viewmats, Ks, width, height,
                                                     eps2d, near_plane, far_plane, radius_clip)  # fmt: skip
    nan = torch.tensor(float("nan"))
    means2d = torch.where(valid[..., None], means2d, nan)  # culled: uninitialised on a GPU
    conics = torch.where(valid[..., None], conics, nan)
    depths = torch.where(valid, depths, nan)
    return radii, means2d.detach(), depths.detach(), conics.detach(), torch.empty(0)


def projection_ewa_3dgs_fused_bwd(means, covars, quats, scales, viewmats, Ks, width, height, eps2d, camera_model,
                                  radii, conics, compensations, v_means2d, v_depths, v_conics, v_compensations,
                                  viewmats_requires_grad):  # fmt: skip
    leaves = [t.detach().requires_grad_(True) for t in (means, quats, scales, viewmats)]
    valid = (radii > 0).all(-1)  # the kernel returns early for culled Gaussians
    with torch.enable_grad():
        _, m2d, z, con, _ = _project(*leaves[:3], None, leaves[3], Ks, width, height, eps2d, 0, 0, -1, keep=valid)
        outs = [torch.where(valid[..., None], m2d, 0), torch.where(valid, z, 0), torch.where(valid[..., None], con, 0)]
        grads = torch.autograd.grad(outs, leaves, [v_means2d, v_depths, v_conics], allow_unused=True)
    v_means, v_quats, v_scales, v_viewmats = grads
    return v_means, None, v_quats, v_scales, v_viewmats if viewmats_requires_grad else None


# ------------------------------------------------------------------------------ tiles


def intersect_tile(means2d, radii, depths, image_ids, gaussian_ids, n_images, tile_size, tile_width, tile_height,
                   sort, segmented):  # fmt: skip
    from gsplat.cuda._torch_impl import _isect_tiles

    assert image_ids is None and gaussian_ids is None, "packed mode is not stood in"
    return _isect_tiles(means2d, radii, depths, tile_size, tile_width, tile_height, sort=sort)


def intersect_offset(isect_ids, n_images, tile_width, tile_height):
    from gsplat.cuda._torch_impl import _isect_offset_encode

    return _isect_offset_encode(isect_ids, n_images, tile_width, tile_height)


# ------------------------------------------------------------------------------ rasterization


def rasterize_to_indices_3dgs(range_start, range_end, transmittances, means2d, conics, opacities, width, height,
                              tile_size, isect_offsets, flatten_ids):  # fmt: skip
    """(Gaussian ids, pixel indices) of every pair that contributes, by pixel, front to back."""
    n_images, tiles_h, tiles_w = isect_offsets.shape[-3:] if isect_offsets.dim() == 3 else (1, *isect_offsets.shape)
    n = means2d.shape[-2]
    m2d, con, opa = means2d.reshape(-1, 2), conics.reshape(-1, 3), opacities.reshape(-1)
    trans0 = transmittances.reshape(n_images, height, width)
    ends = torch.cat([isect_offsets.flatten()[1:], torch.tensor([flatten_ids.numel()])]).tolist()
    starts = isect_offsets.flatten().tolist()
    block = tile_size * tile_size
    lane = torch.arange(tile_size)
    g_out, p_out = [], []
    for tile, (s, e) in enumerate(zip(starts, ends)):
        s, e = s + range_start * block, min(e, s + range_end * block)
        if e <= s:
            continue
        img, t = divmod(tile, tiles_h * tiles_w)
        ty, tx = divmod(t, tiles_w)
        rows, cols = ty * tile_size + lane, tx * tile_size + lane
        py, px = torch.meshgrid(rows, cols, indexing="ij")
        inside = (py < height) & (px < width)
        py, px = py[inside], px[inside]  # [P]
        ids = flatten_ids[s:e].long()  # [K] depth-sorted
        d = m2d[ids][None] - torch.stack([px + 0.5, py + 0.5], -1)[:, None]  # [P, K, 2]
        q = con[ids]
        sigma = 0.5 * (q[:, 0] * d[..., 0] ** 2 + q[:, 2] * d[..., 1] ** 2) + q[:, 1] * d[..., 0] * d[..., 1]
        alpha = torch.clamp_max(opa[ids] * torch.exp(-sigma), 0.999)
        live = (sigma >= 0) & (alpha >= ALPHA_THRESHOLD)
        after = trans0[img, py, px][:, None] * torch.cumprod(torch.where(live, 1 - alpha, 1.0), dim=1)
        keep = live & (after > 1e-4)  # T never rises: nothing after the first stop is kept
        pix = (img * height * width + py * width + px)[:, None].expand_as(keep)
        g_out.append((ids % n)[None].expand_as(keep)[keep])
        p_out.append(pix[keep])
    if not g_out:
        return torch.zeros(0, dtype=torch.int64), torch.zeros(0, dtype=torch.int64)
    g, p = torch.cat(g_out), torch.cat(p_out)
    order = torch.sort(p, stable=True).indices  # by pixel, front to back within each
    return g[order], p[order]


def render_weight_from_alpha(alphas: Tensor, ray_indices: Tensor, n_rays: int) -> tuple[Tensor, Tensor]:
    """nerfacc: weights alpha_k T_k and transmittances T_k (exclusive products) along sorted rays."""
    if alphas.numel() == 0:
        return alphas, alphas
    first = torch.ones_like(ray_indices, dtype=torch.bool)
    first[1:] = ray_indices[1:] != ray_indices[:-1]
    seg = torch.cumsum(first.long(), 0) - 1  # [M] segment id
    start = torch.nonzero(first).squeeze(-1)
    rank = torch.arange(len(alphas)) - start[seg]
    dense = alphas.new_zeros(len(start), int(rank.max()) + 1).index_put((seg, rank), alphas)
    ones = torch.ones_like(dense[:, :1])
    trans = torch.cumprod(torch.cat([ones, 1 - dense[:, :-1]], 1), 1)[seg, rank]
    return alphas * trans, trans


def accumulate_along_rays(weights: Tensor, values: Tensor | None, ray_indices: Tensor, n_rays: int) -> Tensor:
    """nerfacc: sum of weights (times values) per ray -> [n_rays, D]."""
    src = weights[:, None] if values is None else weights[:, None] * values
    return src.new_zeros(n_rays, src.shape[-1]).index_add(0, ray_indices, src)


def _rasterize(means2d, conics, colors, opacities, backgrounds, width, height, tile_size, isect_offsets, flatten_ids):
    from gsplat.cuda._torch_impl import _rasterize_to_pixels

    return _rasterize_to_pixels(means2d, conics, colors, opacities, width, height, tile_size, isect_offsets,
                                flatten_ids, backgrounds=backgrounds)  # fmt: skip


def rasterize_to_pixels_3dgs_fwd(means2d, conics, colors, opacities, backgrounds, masks, width, height, tile_size,
                                 isect_offsets, flatten_ids):  # fmt: skip
    assert masks is None
    image, alpha = _rasterize(means2d, conics, colors, opacities, backgrounds, width, height, tile_size,
                              isect_offsets, flatten_ids)  # fmt: skip
    last_ids = torch.zeros(alpha.shape[:-1], dtype=torch.int32)  # only the CUDA backward reads it
    return image.detach(), alpha.detach(), last_ids


def rasterize_to_pixels_3dgs_bwd(means2d, conics, colors, opacities, backgrounds, masks, width, height, tile_size,
                                 isect_offsets, flatten_ids, render_alphas, last_ids, v_render_colors,
                                 v_render_alphas, absgrad):  # fmt: skip
    leaves = [t.detach().requires_grad_(True) for t in (means2d, conics, colors, opacities)]
    with torch.enable_grad():
        image, alpha = _rasterize(*leaves, backgrounds, width, height, tile_size, isect_offsets, flatten_ids)
        v_m2d, v_con, v_col, v_opa = torch.autograd.grad([image, alpha], leaves, [v_render_colors, v_render_alphas],
                                                         allow_unused=True)  # fmt: skip
    zero = [torch.zeros_like(t) for t in leaves]
    v_m2d, v_con, v_col, v_opa = (g if g is not None else z for g, z in zip((v_m2d, v_con, v_col, v_opa), zero))
    return (v_m2d.abs() if absgrad else None), v_m2d, v_con, v_col, v_opa


# ------------------------------------------------------------------------------ relocation


def relocation(opacities, scales, ratios, binoms, n_max):
    """3DGS-MCMC Eq. 9 (``RelocationCUDA.cu``): the shared opacity, then the scale factor."""
    o_new = 1.0 - torch.pow(1.0 - opacities, 1.0 / ratios.float())
    denom = torch.zeros_like(opacities)
    for j in range(len(opacities)):
        n = int(ratios[j])
        for i in range(1, n + 1):
            for k in range(i):
                term = (-1.0) ** k / math.sqrt(k + 1) * o_new[j] ** (k + 1)
                denom[j] += binoms[i - 1, k] * term
    return o_new, (opacities / denom)[:, None] * scales


# ------------------------------------------------------------------------------ installation

_OPS = (
    projection_ewa_3dgs_fused_fwd, projection_ewa_3dgs_fused_bwd, intersect_tile, intersect_offset,
    rasterize_to_indices_3dgs, rasterize_to_pixels_3dgs_fwd, rasterize_to_pixels_3dgs_bwd, relocation,
)  # fmt: skip


def install(monkeypatch: pytest.MonkeyPatch) -> types.ModuleType:
    """Import gsplat with its CUDA extension and nerfacc replaced by the stand-ins; returns gsplat.

    Skips (with the reason) only when gsplat is not installed; CI installs it (test extra)."""
    gsplat = pytest.importorskip("gsplat", reason="gsplat is not installed (pip install -e '.[test]')")
    assert gsplat.__version__ == "1.5.3", f"the stand-ins follow gsplat 1.5.3, found {gsplat.__version__}"
    backend = types.ModuleType("gsplat.cuda._backend")
    ops = types.SimpleNamespace(**{f.__name__: f for f in _OPS})
    ops.CameraModelType = types.SimpleNamespace(PINHOLE="pinhole")
    ops.PINHOLE = "pinhole"  # _make_lazy_cuda_obj("CameraModelType.PINHOLE") ends at _C.PINHOLE
    backend._C = ops
    nerfacc = types.ModuleType("nerfacc")
    nerfacc.render_weight_from_alpha = render_weight_from_alpha
    nerfacc.accumulate_along_rays = accumulate_along_rays
    monkeypatch.setitem(sys.modules, "gsplat.cuda._backend", backend)
    monkeypatch.setitem(sys.modules, "nerfacc", nerfacc)
    return gsplat
