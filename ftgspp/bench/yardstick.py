"""The fixed yardstick of ``ftgspp bench render``: the rasterizer contract evaluated densely.

Every Gaussian-pixel pair is composited with dense PyTorch tensors, chunked over pixels so
memory stays bounded. It is fixed code, so speed-ups over it stay comparable when a backend
changes; the ``cpu`` backend's tests use it as a third oracle.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ftgspp.render.contract import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE_SIZE
from ftgspp.render.reference import tile_ranges


def dense_rasterize(
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3]
    colors: Tensor,  # [N, D]
    opacities: Tensor,  # [N]
    depths: Tensor,  # [N]
    radii: Tensor,  # [N, 2]
    width: int,
    height: int,
    background: Tensor | None = None,  # [D]
    grads: tuple[Tensor, Tensor, Tensor] | None = None,  # cotangents of image, alpha, depth
    chunk_pairs: int = 1 << 23,
) -> tuple[Tensor, Tensor, Tensor]:
    """The yardstick: the rasterizer contract evaluated densely on every Gaussian-pixel pair.

    Pixels are processed in chunks of about ``chunk_pairs / N`` pixels. With ``grads``, each
    chunk is differentiated right away (``backward`` of <outputs, cotangents>), so gradients
    accumulate in the leaves' ``.grad`` and memory stays bounded. Returns detached outputs.
    """
    n = colors.shape[0]
    order = torch.sort(depths.detach(), stable=True).indices  # [N] front to back
    with torch.no_grad():
        tx0, tx1, ty0, ty1 = (t[order] for t in tile_ranges(means2d, radii, width, height))
    pix = torch.arange(width * height)
    outs: list[list[Tensor]] = [[], [], []]
    step = max(1, chunk_pairs // max(n, 1))
    for start in range(0, width * height, step):
        p = pix[start : start + step]  # [P]
        px, py = (p % width).to(means2d.dtype), (p // width).to(means2d.dtype)
        with torch.no_grad():
            tx, ty = (px // TILE_SIZE).unsqueeze(-1), (py // TILE_SIZE).unsqueeze(-1)  # [P, 1]
            in_tile = (tx >= tx0) & (tx < tx1) & (ty >= ty0) & (ty < ty1)  # [P, N]
        mean, conic = means2d[order], conics[order]
        dx = px.unsqueeze(-1) - mean[:, 0]  # [P, N]
        dy = py.unsqueeze(-1) - mean[:, 1]
        power = -0.5 * conic[:, 0] * dx * dx + -0.5 * conic[:, 2] * dy * dy - conic[:, 1] * dy * dx
        alpha = torch.clamp(opacities[order] * torch.exp(torch.clamp(power, max=0.0)), max=ALPHA_MAX)
        with torch.no_grad():
            keep = in_tile & (power <= 0) & (alpha >= ALPHA_MIN)
        alpha = torch.where(keep, alpha, 0.0)
        trans = torch.cumprod(1.0 - alpha, dim=-1)  # [P, N] T after each Gaussian
        with torch.no_grad():
            alive = trans > T_MIN  # a prefix: T never increases
        alpha = torch.where(alive, alpha, 0.0)
        trans = torch.cumprod(1.0 - alpha, dim=-1)
        t_before = torch.cat([torch.ones_like(trans[:, :1]), trans[:, :-1]], dim=-1)
        weights = alpha * t_before  # [P, N]
        t_final = trans[:, -1:]  # [P, 1]
        image = weights @ colors[order]  # [P, D]
        if background is not None:
            image = image + t_final * background
        depth = weights @ depths[order].unsqueeze(-1)  # [P, 1]
        chunk = (image, 1.0 - t_final, depth)
        if grads is not None:
            cot = [g.reshape(width * height, -1)[start : start + step] for g in grads]
            torch.autograd.backward(chunk, cot)
        for acc, t in zip(outs, chunk):
            acc.append(t.detach())
    image, alpha, depth = (torch.cat(o).reshape(height, width, -1) for o in outs)
    return image, alpha, depth
