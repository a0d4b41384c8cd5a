"""Numba kernels of the ``cpu`` rasterization backend (forward and hand-written backward).

The maths follows the rasterizer contract in ``docs/CONTRACTS.md`` exactly, in float32, with
the power evaluated in the reference rasterizer's rounding order,
``power = (-0.5 a) dx dx + (-0.5 c) dy dy - (b dy) dx``:

1. ``bin_gaussians`` (serial, O(N + pairs)): each Gaussian with radius > 0 and opacity
   >= 1/255 is listed in every 16x16 tile of its radius box (tile ranges computed exactly as
   the contract says); the (tile, Gaussian) pairs are grouped by tile with a counting sort.
   It also fills a per-Gaussian *span table*: the ellipse ``a dx^2 + 2 b dx dy + c dy^2 <= Lm``
   holding every pixel where ``alpha >= 1/255`` can hold (``Lm = 2 ln(255 o)`` widened by a
   bound on float32 rounding). Rows and columns outside it are never visited; the per-pixel
   tests still decide inside, so results are the same as visiting every pixel of the tile.
2. ``balance_tiles``: tiles are dealt to one list per thread, largest estimated cost first
   (LPT), because Numba's ``prange`` splits its range statically.
3. ``render_forward`` (parallel over the lists): sorts each tile's list by
   ``(order-preserving depth bits << 32) | index`` and composites Gaussian by Gaussian, front
   to back, with per-pixel early termination. It keeps the final transmittance and records
   every contribution (exp(power) and the pixel), Gaussian by Gaussian, for the backward pass.
4. ``render_backward`` (parallel over the lists): walks each tile's record back to front,
   recovering transmittance from the final one by division, and writes one gradient row per
   (tile, slot) pair; ``reduce_pair_grads`` sums each Gaussian's rows in the raster order of
   its tiles. Every tile and every Gaussian's sum is computed by one thread, start to end,
   so results are bitwise identical across runs and thread counts.

Float literals are ``np.float32`` constants: a Python float literal would silently promote
float32 maths to float64 inside Numba.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from ftgspp.render import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE_SIZE

F0 = np.float32(0.0)
F1 = np.float32(1.0)
F_HALF = np.float32(0.5)
F_15 = np.float32(TILE_SIZE - 1)
F_TILE = np.float32(TILE_SIZE)
F_ALPHA_MAX = np.float32(ALPHA_MAX)
F_ALPHA_MIN = np.float32(ALPHA_MIN)
F_T_MIN = np.float32(T_MIN)
TS = TILE_SIZE

# Span culling margins (float64 maths, per Gaussian). The float32 quadratic form differs from
# the exact one by at most ~7 roundings (6e-8 each) of S = a dx^2 + c dy^2 + 2|b dx dy|, and
# S <= cond * q with cond <= (a + c)^2 / det; the ellipse is widened by 4 SPAN_REL cond, about
# ten times that. Gaussians whose conic is not positive definite, or too ill-conditioned for
# the bound (cond > 1.25e5), are evaluated on every pixel of their tiles.
SPAN_REL = 1e-6
SPAN_ABS = 1e-4  # absolute slack on q (exp and multiply rounding, float32 1/255)
SPAN_PX = 1e-3  # pixel slack on span end points
# Columns of the span table.
S_FULL, S_MX, S_MY, S_ALM, S_DET, S_YR, S_INVA, S_B = 0, 1, 2, 3, 4, 5, 6, 7
N_SPAN = 8

# Columns of the per-pair gradient rows.
G_MX, G_MY, G_A, G_B, G_C, G_O, G_Z, G_COL = 0, 1, 2, 3, 4, 5, 6, 7

_JIT = dict(cache=True, fastmath=False, error_model="numpy", nogil=True)


class Binning(NamedTuple):
    """Output of ``bin_gaussians``."""

    offsets: np.ndarray  # [n_tiles + 1] int64, each tile's range in pair_gauss
    pair_gauss: np.ndarray  # [P] int32, Gaussian of each (tile, Gaussian) pair, grouped by tile
    span: np.ndarray  # [N, 8] float64, span table (columns S_*)
    tile_cost: np.ndarray  # [n_tiles] float64, estimated pixels to evaluate (load balancing)
    tile_cap: np.ndarray  # [n_tiles] int64, bound on the tile's contributions (record size)
    rect: np.ndarray  # [N, 4] int64, tile range tx0, tx1, ty0, ty1 (empty when culled)
    gauss_off: np.ndarray  # [N + 1] int64, offsets of each Gaussian's pairs (raster tile order)


class Forward(NamedTuple):
    """Output of ``render_forward``."""

    image: np.ndarray  # [H, W, D] float32
    alpha: np.ndarray  # [H, W] float32
    depth: np.ndarray  # [H, W] float32
    t_final: np.ndarray  # [H, W] float32, final transmittance
    rec_gauss: np.ndarray  # [R] float32, exp(power) of every contribution
    rec_pixel: np.ndarray  # [R] uint8, its pixel in the tile (row * 16 + column)
    pair_beg: np.ndarray  # [P] int64, each sorted pair's range in the record
    pair_end: np.ndarray  # [P] int64
    gauss_pairs: np.ndarray  # [P] int64, sorted pair index of each (Gaussian, tile), CSR by gauss_off
    tile_work: np.ndarray  # [n_tiles] float64, contributions per tile


# ------------------------------------------------------------------------------ binning


@njit(**_JIT)
def bin_gaussians(
    means2d: np.ndarray,  # [N, 2] float32
    conics: np.ndarray,  # [N, 3] float32
    opacities: np.ndarray,  # [N] float32
    radii: np.ndarray,  # [N] int64
    width: int,
    height: int,
):
    """Tile lists, span table and the bookkeeping of the later passes (see ``Binning``)."""
    n = means2d.shape[0]
    tiles_x = (width + TS - 1) // TS
    tiles_y = (height + TS - 1) // TS
    n_tiles = tiles_x * tiles_y
    ftx = np.float32(tiles_x)
    fty = np.float32(tiles_y)
    rect = np.zeros((n, 4), np.int64)  # tx0, tx1, ty0, ty1 (empty: tx0 == tx1)
    counts = np.zeros(n_tiles + 1, np.int64)
    span = np.zeros((n, N_SPAN), np.float64)
    half_w = np.zeros(n, np.float64)  # x half-extent of the span ellipse (cost estimate)
    for k in range(n):
        r = radii[k]
        o = opacities[k]
        mx = means2d[k, 0]
        my = means2d[k, 1]
        if r <= 0 or not (o >= F_ALPHA_MIN) or not (np.isfinite(mx) and np.isfinite(my)):
            continue  # culled, or alpha <= o < 1/255 everywhere
        fr = np.float32(r)
        tx0 = min(max(np.floor((mx - fr) / F_TILE), F0), ftx)
        tx1 = min(max(np.floor((mx + fr + F_15) / F_TILE), F0), ftx)
        ty0 = min(max(np.floor((my - fr) / F_TILE), F0), fty)
        ty1 = min(max(np.floor((my + fr + F_15) / F_TILE), F0), fty)
        if tx1 <= tx0 or ty1 <= ty0:
            continue
        rect[k, 0] = np.int64(tx0)
        rect[k, 1] = np.int64(tx1)
        rect[k, 2] = np.int64(ty0)
        rect[k, 3] = np.int64(ty1)
        for ty in range(rect[k, 2], rect[k, 3]):
            for tx in range(rect[k, 0], rect[k, 1]):
                counts[ty * tiles_x + tx + 1] += 1
        a = np.float64(conics[k, 0])
        b = np.float64(conics[k, 1])
        c = np.float64(conics[k, 2])
        det = a * c - b * b
        span[k, S_FULL] = 1.0  # every tile pixel, unless the ellipse bound is safe
        span[k, S_MX] = mx
        span[k, S_MY] = my
        half_w[k] = 1e9
        if a > 0.0 and c > 0.0 and det > 0.0 and np.isfinite(det):
            cond = (a + c) * (a + c) / det
            shrink = 1.0 - 4.0 * SPAN_REL * cond
            if shrink > 0.5:
                lim = 2.0 * math.log(np.float64(o) / np.float64(F_ALPHA_MIN))
                lm = (lim + SPAN_ABS) / shrink
                span[k, S_FULL] = 0.0
                span[k, S_ALM] = a * lm
                span[k, S_DET] = det
                span[k, S_YR] = math.sqrt(a * lm / det) + SPAN_PX
                span[k, S_INVA] = 1.0 / a
                span[k, S_B] = b
                half_w[k] = math.sqrt(c * lm / det) + SPAN_PX
    for t in range(n_tiles):
        counts[t + 1] += counts[t]
    offsets = counts
    fill = offsets[:n_tiles].copy()
    pair_gauss = np.empty(offsets[n_tiles], np.int32)
    tile_cost = np.zeros(n_tiles, np.float64)
    tile_cap = np.zeros(n_tiles, np.int64)
    for k in range(n):
        for ty in range(rect[k, 2], rect[k, 3]):
            y0 = ty * TS
            r0, r1 = _row_range(span, k, y0, min(y0 + TS, height))
            rows = _overlap(span[k, S_MY], span[k, S_YR] if span[k, S_FULL] == 0.0 else 1e9, y0)
            for tx in range(rect[k, 0], rect[k, 1]):
                t = ty * tiles_x + tx
                pair_gauss[fill[t]] = k
                fill[t] += 1
                cols = _overlap(span[k, S_MX], half_w[k], tx * TS)
                tile_cost[t] += 1.0 + rows * cols
                # Bound on the pixels this pair can contribute to: its rows times its column
                # extent (+2 for float64 rounding of the per-row spans), at most a tile row.
                tile_cap[t] += (r1 - r0) * min(TS, np.int64(cols) + 3)
    gauss_off = np.zeros(n + 1, np.int64)  # CSR of each Gaussian's pairs, in tile order
    for k in range(n):
        gauss_off[k + 1] = gauss_off[k] + (rect[k, 1] - rect[k, 0]) * (rect[k, 3] - rect[k, 2])
    return Binning(offsets, pair_gauss, span, tile_cost, tile_cap, rect, gauss_off)


@njit(**_JIT)
def _overlap(centre: float, half: float, start: int) -> float:
    """Length of [centre - half, centre + half] inside the tile span [start, start + TS)."""
    lo = max(centre - half, np.float64(start))
    hi = min(centre + half, np.float64(start + TS))
    return max(hi - lo, 0.0)


@njit(**_JIT)
def balance_tiles(tile_cost: np.ndarray, n_workers: int):
    """Deal tiles to ``n_workers`` lists, costliest first, each to the least loaded list.

    Returns ``worker_offsets [n_workers + 1]`` and ``worker_tiles [n_tiles]`` (CSR).
    Which worker computes a tile never changes its results.
    """
    n_tiles = tile_cost.shape[0]
    # Decreasing cost, ties by tile index: sort (cost << 32 | reversed index) and walk back.
    keys = np.empty(n_tiles, np.uint64)
    for t in range(n_tiles):
        c = np.uint64(min(max(tile_cost[t], 0.0), 4e9))
        keys[t] = (c << np.uint64(32)) | np.uint64(n_tiles - 1 - t)
    keys.sort()
    order = np.empty(n_tiles, np.int64)
    for j in range(n_tiles):
        order[j] = n_tiles - 1 - np.int64(keys[n_tiles - 1 - j] & np.uint64(0xFFFFFFFF))
    owner = np.zeros(n_tiles, np.int64)
    load = np.zeros(n_workers, np.float64)
    for t in order:
        best = 0
        for w in range(1, n_workers):
            if load[w] < load[best]:
                best = w
        owner[t] = best
        load[best] += tile_cost[t]
    worker_offsets = np.zeros(n_workers + 1, np.int64)
    for t in range(n_tiles):
        worker_offsets[owner[t] + 1] += 1
    for w in range(n_workers):
        worker_offsets[w + 1] += worker_offsets[w]
    fill = worker_offsets[:n_workers].copy()
    worker_tiles = np.empty(n_tiles, np.int64)
    for t in order:
        worker_tiles[fill[owner[t]]] = t
        fill[owner[t]] += 1
    return worker_offsets, worker_tiles


@njit(**_JIT)
def _row_range(span: np.ndarray, g: int, y0: int, y1: int):
    """Rows [r0, r1) of the tile rows [y0, y1) that may hold pixels of Gaussian g."""
    if span[g, S_FULL] != 0.0:
        return y0, y1
    my = span[g, S_MY]
    yr = span[g, S_YR]
    r0 = max(np.float64(y0), np.ceil(my - yr))
    r1 = min(np.float64(y1 - 1), np.floor(my + yr))
    if r1 < r0:
        return 0, 0
    return np.int64(r0), np.int64(r1) + 1


@njit(**_JIT)
def _col_range(span: np.ndarray, g: int, py: int, x0: int, x1: int):
    """Columns [c0, c1) of row py inside [x0, x1) that may hold pixels of Gaussian g."""
    if span[g, S_FULL] != 0.0:
        return x0, x1
    dy = np.float64(py) - span[g, S_MY]
    disc = span[g, S_ALM] - span[g, S_DET] * dy * dy
    if disc < 0.0:
        return 0, 0
    inv_a = span[g, S_INVA]
    half = math.sqrt(disc) * inv_a + SPAN_PX
    xc = span[g, S_MX] - span[g, S_B] * dy * inv_a
    c0 = max(np.float64(x0), np.ceil(xc - half))
    c1 = min(np.float64(x1 - 1), np.floor(xc + half))
    if c1 < c0:
        return 0, 0
    return np.int64(c0), np.int64(c1) + 1


# ------------------------------------------------------------------------------ forward


@njit(**_JIT)
def _forward_tile(
    tile, means2d, conics, colors, opacities, depths, depth_keys, background, offsets, pair_gauss,
    span, rect, gauss_off, gauss_pairs, rec_offsets, rec_gauss, rec_pixel, pair_beg, pair_end, image,
    alpha_out, depth_out, t_final,
):  # fmt: skip
    """Sort one tile's list by depth, composite its pixels into the outputs and record every
    contribution: for slot i, entries [pair_beg, pair_end) hold exp(power) and the pixel.
    Also notes where each of the tile's pairs landed in ``gauss_pairs`` (per-Gaussian CSR).

    Returns the number of contributions (the backward pass's load estimate); if that
    exceeds the tile's record capacity, the record is incomplete and must not be used.
    """
    height, width = t_final.shape
    n_dim = colors.shape[1]
    tiles_x = (width + TS - 1) // TS
    start = offsets[tile]
    count = offsets[tile + 1] - start
    keys = np.empty(count, np.uint64)
    for i in range(count):
        g = pair_gauss[start + i]
        keys[i] = (np.uint64(depth_keys[g]) << np.uint64(32)) | np.uint64(g)
    keys.sort()
    tx = tile % tiles_x
    ty = tile // tiles_x
    for i in range(count):
        g = np.int64(keys[i] & np.uint64(0xFFFFFFFF))
        pair_gauss[start + i] = g
        local = (ty - rect[g, 2]) * (rect[g, 1] - rect[g, 0]) + (tx - rect[g, 0])
        gauss_pairs[gauss_off[g] + local] = start + i

    x0 = tx * TS
    y0 = ty * TS
    x1 = min(x0 + TS, width)
    y1 = min(y0 + TS, height)
    # Per-pixel state [row, column] in the tile. trans = 0 marks a pixel that has stopped
    # (it is >= T_MIN > 0 otherwise); its transmittance is then kept in t_stop.
    trans = np.ones((TS, TS), np.float32)
    t_stop = np.ones((TS, TS), np.float32)
    acc = np.zeros((TS, TS, n_dim), np.float32)
    acc_z = np.zeros((TS, TS), np.float32)
    row_active = np.zeros(TS, np.int64)
    for py in range(y0, y1):
        row_active[py - y0] = x1 - x0
    active = (x1 - x0) * (y1 - y0)
    cursor = rec_offsets[tile]
    rec_end = rec_offsets[tile + 1]
    for i in range(count):
        pair_beg[start + i] = cursor
        if active == 0:
            pair_end[start + i] = cursor
            continue
        g = pair_gauss[start + i]
        mx = means2d[g, 0]
        my = means2d[g, 1]
        nh_a = -F_HALF * conics[g, 0]
        nh_c = -F_HALF * conics[g, 2]
        cb = conics[g, 1]
        op = opacities[g]
        z = depths[g]
        r0, r1 = _row_range(span, g, y0, y1)
        for py in range(r0, r1):
            row = py - y0
            if row_active[row] == 0:
                continue
            c0, c1 = _col_range(span, g, py, x0, x1)
            dy = np.float32(py) - my
            quad_y = nh_c * dy * dy
            b_dy = cb * dy
            for px in range(c0, c1):
                col = px - x0
                t = trans[row, col]
                if t == F0:
                    continue
                dx = np.float32(px) - mx
                power = nh_a * dx * dx + quad_y - b_dy * dx
                if power > F0:
                    continue
                gauss = math.exp(power)
                al = min(op * gauss, F_ALPHA_MAX)
                if al < F_ALPHA_MIN:
                    continue
                t_next = t * (F1 - al)
                if t_next < F_T_MIN:
                    t_stop[row, col] = t
                    trans[row, col] = F0
                    active -= 1
                    row_active[row] -= 1
                    continue
                w = al * t
                if n_dim == 3:
                    acc[row, col, 0] += w * colors[g, 0]
                    acc[row, col, 1] += w * colors[g, 1]
                    acc[row, col, 2] += w * colors[g, 2]
                else:
                    for ch in range(n_dim):
                        acc[row, col, ch] += w * colors[g, ch]
                acc_z[row, col] += w * z
                trans[row, col] = t_next
                if cursor < rec_end:  # else the caller retries with a larger record
                    rec_gauss[cursor] = gauss
                    rec_pixel[cursor] = np.uint8(row * TS + col)
                cursor += 1
        pair_end[start + i] = cursor
    for py in range(y0, y1):
        for px in range(x0, x1):
            row, col = py - y0, px - x0
            t = trans[row, col]
            if t == F0:
                t = t_stop[row, col]
            for ch in range(n_dim):
                image[py, px, ch] = acc[row, col, ch] + t * background[ch]
            alpha_out[py, px] = F1 - t
            depth_out[py, px] = acc_z[row, col]
            t_final[py, px] = t
    return cursor - rec_offsets[tile]


@njit(**_JIT)
def _forward_outputs(pair_gauss, tile_cap, n_dim, width, height):
    """Uninitialised outputs of the forward pass (see ``render_forward``)."""
    n_tiles = tile_cap.shape[0]
    rec_offsets = np.zeros(n_tiles + 1, np.int64)
    for t in range(n_tiles):
        rec_offsets[t + 1] = rec_offsets[t] + tile_cap[t]
    return (
        np.empty((height, width, n_dim), np.float32),  # image
        np.empty((height, width), np.float32),  # alpha
        np.empty((height, width), np.float32),  # depth
        np.empty((height, width), np.float32),  # final transmittance
        rec_offsets,
        np.empty(rec_offsets[n_tiles], np.float32),  # recorded exp(power)
        np.empty(rec_offsets[n_tiles], np.uint8),  # recorded pixel-in-tile
        np.empty(pair_gauss.shape[0], np.int64),  # pair_beg
        np.empty(pair_gauss.shape[0], np.int64),  # pair_end
        np.empty(pair_gauss.shape[0], np.int64),  # gauss_pairs: pair index per (Gaussian, tile)
        np.zeros(n_tiles, np.float64),  # contributions per tile
    )


@njit(parallel=True, **_JIT)
def render_forward(
    means2d: np.ndarray,  # [N, 2] float32
    conics: np.ndarray,  # [N, 3] float32
    colors: np.ndarray,  # [N, D] float32
    opacities: np.ndarray,  # [N] float32
    depths: np.ndarray,  # [N] float32
    depth_keys: np.ndarray,  # [N] uint32, order-preserving bits of depth
    background: np.ndarray,  # [D] float32
    offsets: np.ndarray,  # [n_tiles + 1] int64
    pair_gauss: np.ndarray,  # [P] int32, sorted in place per tile by (depth, index)
    span: np.ndarray,  # [N, 8] float64
    tile_cap: np.ndarray,  # [n_tiles] int64, bound on each tile's contributions
    rect: np.ndarray,  # [N, 4] int64
    gauss_off: np.ndarray,  # [N + 1] int64
    worker_offsets: np.ndarray,  # [W + 1] int64
    worker_tiles: np.ndarray,  # [n_tiles] int64
    width: int,
    height: int,
):
    """Composite every tile (see ``Forward``); sorts ``pair_gauss`` in place per tile."""
    image, alpha, depth, t_final, rec_off, rec_g, rec_p, beg, end, gauss_pairs, work = _forward_outputs(
        pair_gauss, tile_cap, colors.shape[1], width, height
    )
    for w in prange(worker_offsets.shape[0] - 1):
        for j in range(worker_offsets[w], worker_offsets[w + 1]):
            tile = worker_tiles[j]
            work[tile] = _forward_tile(
                tile, means2d, conics, colors, opacities, depths, depth_keys, background, offsets,
                pair_gauss, span, rect, gauss_off, gauss_pairs, rec_off, rec_g, rec_p, beg, end, image,
                alpha, depth, t_final,
            )  # fmt: skip
    return Forward(image, alpha, depth, t_final, rec_g, rec_p, beg, end, gauss_pairs, work)


# ----------------------------------------------------------------------------- backward


@njit(**_JIT)
def _backward_tile(
    tile, means2d, conics, colors, opacities, depths, background, offsets, pair_gauss, rec_gauss,
    rec_pixel, pair_beg, pair_end, t_final, grad_image, grad_alpha, grad_depth, pair_grads, bg_grads,
):  # fmt: skip
    """Walk one tile's recorded contributions back to front; write its gradient rows and
    its background gradient.

    With w_i = alpha_i T_i and <g, f_i> the output cotangent dotted with Gaussian i's
    colour and depth, dL/dalpha_i = T_i <g, f_i> - rest_i / (1 - alpha_i), where
    rest_i = sum_{j > i} w_j <g, f_j> + T_final (<g_image, background> - g_alpha).
    T_i is recovered from T_final as T_{i+1} / (1 - alpha_i).
    """
    height, width = t_final.shape
    n_dim = colors.shape[1]
    tiles_x = (width + TS - 1) // TS
    start = offsets[tile]
    count = offsets[tile + 1] - start
    x0 = (tile % tiles_x) * TS
    y0 = (tile // tiles_x) * TS
    x1 = min(x0 + TS, width)
    y1 = min(y0 + TS, height)
    # Per-pixel state, indexed by pixel-in-tile (row * TS + column).
    trans = np.zeros(TS * TS, np.float32)  # T after the slot being visited
    rest = np.zeros(TS * TS, np.float32)
    g_img = np.zeros((TS * TS, n_dim), np.float32)
    g_z = np.zeros(TS * TS, np.float32)
    for ch in range(n_dim):
        bg_grads[tile, ch] = 0.0
    for py in range(y0, y1):
        for px in range(x0, x1):
            p = (py - y0) * TS + (px - x0)
            t = t_final[py, px]
            trans[p] = t
            dot_bg = F0
            for ch in range(n_dim):
                gc = grad_image[py, px, ch]
                g_img[p, ch] = gc
                dot_bg += gc * background[ch]
                bg_grads[tile, ch] += np.float64(gc * t)
            g_z[p] = grad_depth[py, px]
            rest[p] = t * dot_bg - grad_alpha[py, px] * t
    g_col = np.zeros(n_dim, np.float64)
    fx0 = np.float32(x0)
    fy0 = np.float32(y0)
    for i in range(count - 1, -1, -1):
        out = pair_grads[start + i]
        beg = pair_beg[start + i]
        end = pair_end[start + i]
        if beg == end:
            out[:] = 0.0
            continue
        g = pair_gauss[start + i]
        mx = means2d[g, 0]
        my = means2d[g, 1]
        op = opacities[g]
        z = depths[g]
        # Moments of dL/dpower over the footprint, from which the mean and conic gradients
        # follow: sum dp dx, sum dp dy, sum dp dx^2, sum dp dx dy, sum dp dy^2.
        m_x = 0.0
        m_y = 0.0
        m_xx = 0.0
        m_xy = 0.0
        m_yy = 0.0
        s_o = 0.0
        s_z = 0.0
        g_col[:] = 0.0
        for e in range(beg, end):
            p = np.int64(rec_pixel[e])
            gauss = rec_gauss[e]
            raw = op * gauss
            al = min(raw, F_ALPHA_MAX)
            inv_one_minus = F1 / (F1 - al)
            t = trans[p] * inv_one_minus
            w = al * t
            gz = g_z[p]
            s_z += np.float64(gz * w)
            dot = gz * z
            if n_dim == 3:
                g0 = g_img[p, 0]
                g1 = g_img[p, 1]
                g2 = g_img[p, 2]
                dot += g0 * colors[g, 0] + g1 * colors[g, 1] + g2 * colors[g, 2]
                g_col[0] += np.float64(g0 * w)
                g_col[1] += np.float64(g1 * w)
                g_col[2] += np.float64(g2 * w)
            else:
                for ch in range(n_dim):
                    gc = g_img[p, ch]
                    dot += gc * colors[g, ch]
                    g_col[ch] += np.float64(gc * w)
            d_alpha = t * dot - rest[p] * inv_one_minus
            rest[p] += w * dot
            trans[p] = t
            if raw <= F_ALPHA_MAX:  # else clamped: alpha depends on neither o nor the power
                s_o += np.float64(d_alpha * gauss)
                d_power = np.float64(d_alpha * raw)
                dx = np.float64(fx0 + np.float32(p % TS) - mx)
                dy = np.float64(fy0 + np.float32(p // TS) - my)
                m_x += d_power * dx
                m_y += d_power * dy
                m_xx += d_power * dx * dx
                m_xy += d_power * dx * dy
                m_yy += d_power * dy * dy
        # power = -0.5 (a dx^2 + c dy^2) - b dx dy, dx = px - mx, dy = py - my
        ca = np.float64(conics[g, 0])
        cb = np.float64(conics[g, 1])
        cc = np.float64(conics[g, 2])
        out[G_MX] = ca * m_x + cb * m_y
        out[G_MY] = cc * m_y + cb * m_x
        out[G_A] = -0.5 * m_xx
        out[G_B] = -m_xy
        out[G_C] = -0.5 * m_yy
        out[G_O] = s_o
        out[G_Z] = s_z
        for ch in range(n_dim):
            out[G_COL + ch] = g_col[ch]


@njit(parallel=True, **_JIT)
def render_backward(
    means2d: np.ndarray,  # [N, 2] float32
    conics: np.ndarray,  # [N, 3] float32
    colors: np.ndarray,  # [N, D] float32
    opacities: np.ndarray,  # [N] float32
    depths: np.ndarray,  # [N] float32
    background: np.ndarray,  # [D] float32
    offsets: np.ndarray,  # [n_tiles + 1] int64
    pair_gauss: np.ndarray,  # [P] int32, as sorted by render_forward
    rec_gauss: np.ndarray,  # [R] float32, from render_forward
    rec_pixel: np.ndarray,  # [R] uint8
    pair_beg: np.ndarray,  # [P] int64
    pair_end: np.ndarray,  # [P] int64
    worker_offsets: np.ndarray,  # [W + 1] int64
    worker_tiles: np.ndarray,  # [n_tiles] int64
    t_final: np.ndarray,  # [H, W] float32
    grad_image: np.ndarray,  # [H, W, D] float32
    grad_alpha: np.ndarray,  # [H, W] float32
    grad_depth: np.ndarray,  # [H, W] float32
):
    """Per-(tile, slot) gradient rows [P, 7 + D] float64 (columns G_*) and per-tile
    background gradients [n_tiles, D] float64."""
    n_dim = colors.shape[1]
    pair_grads = np.empty((pair_gauss.shape[0], G_COL + n_dim), np.float64)
    bg_grads = np.empty((offsets.shape[0] - 1, n_dim), np.float64)
    for w in prange(worker_offsets.shape[0] - 1):
        for j in range(worker_offsets[w], worker_offsets[w + 1]):
            _backward_tile(
                worker_tiles[j], means2d, conics, colors, opacities, depths, background, offsets,
                pair_gauss, rec_gauss, rec_pixel, pair_beg, pair_end, t_final, grad_image, grad_alpha,
                grad_depth, pair_grads, bg_grads,
            )  # fmt: skip
    return pair_grads, bg_grads


@njit(parallel=True, **_JIT)
def reduce_pair_grads(pair_grads: np.ndarray, gauss_off: np.ndarray, gauss_pairs: np.ndarray, bg_grads: np.ndarray):
    """Sum each Gaussian's gradient rows in the raster order of its tiles (deterministic).

    Sums are float64, stored rounded to float32 per rasterizer input: returns the gradients
    of ``means2d [N, 2]``, ``conics [N, 3]``, ``colors [N, D]``, ``opacities [N]``,
    ``depths [N]`` (float32) and ``background [D]`` (float64).
    """
    n = gauss_off.shape[0] - 1
    n_cols = pair_grads.shape[1]
    n_dim = n_cols - G_COL
    g_m2d = np.empty((n, 2), np.float32)
    g_con = np.empty((n, 3), np.float32)
    g_col = np.empty((n, n_dim), np.float32)
    g_op = np.empty(n, np.float32)
    g_z = np.empty(n, np.float32)
    block = 256
    for b in prange((n + block - 1) // block):
        acc = np.empty(n_cols, np.float64)
        for k in range(b * block, min(n, (b + 1) * block)):
            acc[:] = 0.0
            for q in range(gauss_off[k], gauss_off[k + 1]):
                pair = gauss_pairs[q]
                for j in range(n_cols):
                    acc[j] += pair_grads[pair, j]
            g_m2d[k, 0] = acc[G_MX]
            g_m2d[k, 1] = acc[G_MY]
            g_con[k, 0] = acc[G_A]
            g_con[k, 1] = acc[G_B]
            g_con[k, 2] = acc[G_C]
            g_op[k] = acc[G_O]
            g_z[k] = acc[G_Z]
            for ch in range(n_dim):
                g_col[k, ch] = acc[G_COL + ch]
    grad_bg = np.zeros(bg_grads.shape[1], np.float64)
    for t in range(bg_grads.shape[0]):
        for ch in range(bg_grads.shape[1]):
            grad_bg[ch] += bg_grads[t, ch]
    return g_m2d, g_con, g_col, g_op, g_z, grad_bg
