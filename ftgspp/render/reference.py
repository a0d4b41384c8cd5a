"""Reference tile rasterizer: pure PyTorch autograd, the oracle for every faster backend.

Implements the rasterizer contract of ``ftgspp/render/contract.py`` literally:

1. Each Gaussian with radii (rx, ry) > 0 covers the tiles tx in [tx0, tx1), ty in [ty0, ty1),
   tx0 = clamp(floor(x'/16 - rx/16), 0, TX), tx1 = clamp(ceil(x'/16 + rx/16), 0, TX) with
   x' = x + 0.5, in float32 (``tile_ranges``). A pixel only sees the Gaussians of its tile.
2. Per tile, Gaussians are sorted by depth (ties by index).
3. Per pixel: power = -0.5 (a dx^2 + c dy^2) - b dx dy, skip if power > 0;
   alpha = min(0.999, o exp(power)), skip if alpha < 1/255; stop (without adding it) at the
   first Gaussian whose T (1 - alpha) <= 1e-4; otherwise add weight alpha T and update T.

Vectorisation: tiles are processed in chunks; each chunk pads its tiles' depth-sorted
lists to the chunk's longest list and evaluates every (tile, Gaussian, pixel) triple as a
dense [tiles, K, 256] tensor. Skipped Gaussians get alpha 0, transmittance is a cumulative
product of (1 - alpha), and early termination is a mask on it (T never increases, so the
Gaussians added are exactly those whose T_next > 1e-4). The masks carry no gradient, so
autograd gives the exact gradient of this piecewise-smooth function (zero through the 0.999
clamp where it is active, nothing through the selections).

    image, alpha, depth = rasterize(means2d, conics, colors, opacities, depths, radii, W, H)
"""

from __future__ import annotations

import torch
from torch import Tensor

from ftgspp.render.contract import ALPHA_MAX, ALPHA_MIN, PIXEL_OFFSET, T_MIN, TILE_SIZE

# Upper bound on tiles * K * pixels evaluated at once (bounds memory, not results).
CHUNK_ELEMENTS = 1 << 20


def tile_grid(width: int, height: int) -> tuple[int, int]:
    """Number of tiles (TX, TY) covering a width x height image."""
    return (width + TILE_SIZE - 1) // TILE_SIZE, (height + TILE_SIZE - 1) // TILE_SIZE


def tile_ranges(means2d: Tensor, radii: Tensor, width: int, height: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Tile rectangle [tx0, tx1) x [ty0, ty1) of each Gaussian; empty when a radius is 0.

    means2d [N, 2], radii [N, 2] -> four int64 tensors [N]. Float32 arithmetic in the order
    of gsplat's ``IntersectTile.cu`` (on its pixel coordinates, ours + 0.5).
    """
    tiles_x, tiles_y = tile_grid(width, height)
    ts = torch.tensor(float(TILE_SIZE), dtype=torch.float32, device=means2d.device)
    centre = (means2d.detach().to(torch.float32) + PIXEL_OFFSET) / ts  # [N, 2] in tiles
    r = radii.to(torch.float32) / ts  # [N, 2]
    lo = torch.floor(centre - r)
    hi = torch.ceil(centre + r)
    limit = torch.tensor([tiles_x, tiles_y], dtype=torch.float32, device=means2d.device)
    lo = torch.minimum(lo.clamp_min(0), limit).long()
    hi = torch.minimum(hi.clamp_min(0), limit).long()
    culled = (radii <= 0).any(dim=-1)
    hi = torch.where(culled.unsqueeze(-1), lo, hi)
    return lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]


def tile_intersections(
    means2d: Tensor, depths: Tensor, radii: Tensor, width: int, height: int
) -> tuple[Tensor, Tensor]:
    """All (tile, Gaussian) pairs, grouped by tile and depth-sorted (ties by index) within it.

    Returns ``(tile_ids [M], gauss_ids [M])`` (int64), sorted by tile id.
    """
    tiles_x, _ = tile_grid(width, height)
    tx0, tx1, ty0, ty1 = tile_ranges(means2d, radii, width, height)
    order = torch.sort(depths.detach(), stable=True).indices  # [N] front to back, ties by index
    span_x = (tx1 - tx0)[order]  # [N]
    counts = span_x * (ty1 - ty0)[order]  # [N] tiles touched, in depth order
    gauss = torch.repeat_interleave(order, counts)  # [M]
    first = torch.repeat_interleave(torch.cumsum(counts, 0) - counts, counts)  # [M]
    local = torch.arange(gauss.numel(), device=gauss.device) - first  # [M] index in its rectangle
    span = torch.repeat_interleave(span_x, counts)  # [M]
    tx = tx0[gauss] + local % span.clamp_min(1)
    ty = ty0[gauss] + local // span.clamp_min(1)
    tile = ty * tiles_x + tx  # [M]
    tile, perm = torch.sort(tile, stable=True)  # stable: keeps depth order inside a tile
    return tile, gauss[perm]


def _composite_tiles(
    tile_ids: Tensor,  # [T] tiles of this chunk
    lists: Tensor,  # [T, K] Gaussian ids, depth-sorted, padded
    present: Tensor,  # [T, K] False on padding
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3]
    opacities: Tensor,  # [N]
    feats: Tensor,  # [N, F] colours and depth
    tiles_x: int,
) -> tuple[Tensor, Tensor]:
    """Alpha-composite the pixels of a chunk of tiles -> (sum w f [T, 256, F], T_final [T, 256]).

    Pixel p of a tile is (row ly, column lx) = divmod(p, 16).
    """
    n_tiles, k = lists.shape
    lane = torch.arange(TILE_SIZE, device=means2d.device, dtype=means2d.dtype)  # [16]
    x0 = ((tile_ids % tiles_x) * TILE_SIZE).to(means2d.dtype)  # [T] tile origin
    y0 = ((tile_ids // tiles_x) * TILE_SIZE).to(means2d.dtype)
    mean = means2d[lists]  # [T, K, 2]
    conic = conics[lists]  # [T, K, 3]
    # The quadratic form is separable over the tile's columns and rows; only the
    # cross term needs the full [T, K, 16, 16] grid.
    dx = (x0.view(-1, 1, 1) + lane) - mean[..., 0:1]  # [T, K, 16] per column
    dy = (y0.view(-1, 1, 1) + lane) - mean[..., 1:2]  # [T, K, 16] per row
    a, b, c = conic[..., 0:1], conic[..., 1:2], conic[..., 2:3]  # [T, K, 1]
    quad_x = (-0.5 * a * dx * dx).unsqueeze(-2)  # [T, K, 1, 16]
    quad_y = (-0.5 * c * dy * dy).unsqueeze(-1)  # [T, K, 16, 1]
    cross = (b * dy).unsqueeze(-1) * dx.unsqueeze(-2)  # [T, K, 16, 16]
    power = (quad_x + quad_y - cross).reshape(n_tiles, k, -1)  # [T, K, 256]

    # Skips: power > 0 -> exp(-inf) = 0, padding -> opacity 0; both then fail alpha >= 1/255.
    power = torch.where(power > 0, -torch.inf, power)
    opacity = torch.where(present, opacities[lists], 0.0).unsqueeze(-1)  # [T, K, 1]
    alpha = torch.clamp(opacity * torch.exp(power), max=ALPHA_MAX)  # [T, K, 256]
    alpha = torch.where(alpha >= ALPHA_MIN, alpha, 0.0)

    # trans[:, k] = T before the k-th Gaussian, trans[:, k + 1] = T_next of the k-th.
    ones = torch.ones_like(alpha[:, :1])
    trans = torch.cumprod(torch.cat([ones, 1.0 - alpha], dim=1), dim=1)  # [T, K + 1, 256]
    # Early termination: T never increases, so the Gaussians with T_next > T_MIN are exactly
    # those before the stop; T before them is unaffected by what the stop discards.
    with torch.no_grad():
        alive = trans > T_MIN  # [T, K + 1, 256], a prefix along K
        last = alive.sum(dim=1, keepdim=True) - 1  # [T, 1, 256] index of T_final
    weights = torch.where(alive[:, 1:], alpha * trans[:, :-1], 0.0)  # [T, K, 256] = alpha_k T_k
    accum = torch.einsum("tkp,tkf->tpf", weights, feats[lists])  # [T, 256, F]
    return accum, trans.gather(1, last).squeeze(1)


def rasterize(
    means2d: Tensor,  # [N, 2]
    conics: Tensor,  # [N, 3] (a, b, c) upper triangle of the inverse 2D covariance
    colors: Tensor,  # [N, D]
    opacities: Tensor,  # [N] in [0, 1]
    depths: Tensor,  # [N]
    radii: Tensor,  # [N, 2] int, 0 = culled
    width: int,
    height: int,
    background: Tensor | None = None,  # [D]
) -> tuple[Tensor, Tensor, Tensor]:
    """Composite projected Gaussians -> (image [H, W, D], alpha [H, W, 1], depth [H, W, 1])."""
    tiles_x, tiles_y = tile_grid(width, height)
    n_tiles, n_pix = tiles_x * tiles_y, TILE_SIZE * TILE_SIZE
    feats = torch.cat([colors, depths.unsqueeze(-1).to(colors.dtype)], dim=-1)  # [N, D + 1]

    tile_of_pair, gauss_of_pair = tile_intersections(means2d, depths, radii, width, height)
    counts = torch.bincount(tile_of_pair, minlength=n_tiles)  # [n_tiles]
    starts = torch.cumsum(counts, 0) - counts
    busy = torch.argsort(counts, descending=True, stable=True)
    busy = busy[counts[busy] > 0]  # non-empty tiles, longest lists first

    accum = feats.new_zeros(n_tiles, n_pix, feats.shape[-1])
    trans = feats.new_ones(n_tiles, n_pix)
    counts_list = counts[busy].tolist()
    i = 0
    while i < len(busy):
        k = counts_list[i]  # longest list in the chunk
        j = min(len(busy), i + max(1, CHUNK_ELEMENTS // (k * n_pix)))
        ids = busy[i:j]  # [T]
        slot = torch.arange(k, device=counts.device)  # [K]
        present = slot < counts[ids].unsqueeze(-1)  # [T, K]
        pair = (starts[ids].unsqueeze(-1) + slot).clamp(max=gauss_of_pair.numel() - 1)
        lists = gauss_of_pair[pair]  # [T, K]
        acc, t_final = _composite_tiles(ids, lists, present, means2d, conics, opacities, feats, tiles_x)
        accum = accum.index_copy(0, ids, acc)
        trans = trans.index_copy(0, ids, t_final)
        i = j

    def to_image(t: Tensor) -> Tensor:  # [n_tiles, 256, C] -> [H, W, C]
        t = t.reshape(tiles_y, tiles_x, TILE_SIZE, TILE_SIZE, -1).permute(0, 2, 1, 3, 4)
        return t.reshape(tiles_y * TILE_SIZE, tiles_x * TILE_SIZE, -1)[:height, :width]

    out = to_image(accum)  # [H, W, D + 1]
    t_final = to_image(trans.unsqueeze(-1))  # [H, W, 1]
    image = out[..., :-1]
    if background is not None:
        image = image + t_final * background
    return image, 1.0 - t_final, out[..., -1:]
