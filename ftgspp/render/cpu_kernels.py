"""Numba kernels of the ``cpu`` rasterization backend (forward and hand-written backward).

The maths follows the rasterizer contract in ``ftgspp/render/contract.py`` in float32, with the
power evaluated in the reference rasterizer's rounding order,
``power = (-0.5 a) dx dx + (-0.5 c) dy dy - (b dy) dx``, and ``exp`` computed by
``exp_clamped`` (pure float32 arithmetic, within 1 ulp of the exact value):

1. ``bin_gaussians`` (serial, O(N + pairs)): each Gaussian with radii > 0 and opacity
   >= 1/255 is listed in every 16x16 tile of its radius box (tile ranges computed exactly as
   the contract says); the (tile, Gaussian) pairs are grouped by tile with a counting sort.
   It also fills a per-Gaussian *span table*: the row and column extent of the ellipse
   ``a dx^2 + 2 b dx dy + c dy^2 <= Lm`` that holds every pixel where ``alpha >= 1/255``
   can hold (``Lm = 2 ln(255 o)`` widened by a bound on float32 rounding). In each tile only
   the rows this ellipse crosses within the tile's columns are visited (none when it misses
   them); the per-pixel tests decide inside, so results are the same as visiting every
   pixel of the tile.
2. ``balance_tiles``: tiles are dealt to one list per thread, largest estimated cost first
   (LPT), because Numba's ``prange`` splits its range statically.
3. ``render_forward`` (parallel over the lists): sorts each tile's list by
   ``(order-preserving depth bits << 32) | index`` (a stable radix sort on the depth bits of
   the index-ordered list) and composites Gaussian by Gaussian,
   front to back. A Gaussian is evaluated on its tile rows in blocks of ``RB`` columns, one
   vector of the compile target's float32 lanes (16 with AVX-512, 8 with AVX2), skipping the
   blocks its column span misses; each block is one branch-free loop that the compiler
   vectorises, and per-pixel masks do the contract's tests and the early termination. Per pixel it keeps the final transmittance and the slot of the Gaussian
   that stopped the pixel, nothing per contribution.
4. ``render_backward`` (parallel over the lists): walks each tile's list back to front,
   recomputing every Gaussian's alphas exactly as the forward pass did (same code, same
   bits), recovering transmittance from the final one by division, and writes one gradient
   row per (tile, slot) pair; ``reduce_pair_grads`` sums each Gaussian's rows in the raster
   order of its tiles. Every tile and every Gaussian's sum is computed by one thread, start
   to end, in a fixed order, so results are bitwise identical across runs and thread
   counts; the kernels use no libm call and no fast-math, so also across x86-64 ISAs.

Index arithmetic in the vectorised loops is unsigned (``np.uint64``): Numba wraps negative
signed indices, and that select stops LLVM from vectorising. Float literals are
``np.float32`` constants: a Python float literal would silently promote float32 maths to
float64 inside Numba.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic

from ftgspp.render.contract import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE_SIZE
from ftgspp.runtime.jit import JIT, allow_short_vector_loops, vector_lanes

F0 = np.float32(0.0)
F1 = np.float32(1.0)
F_HALF = np.float32(0.5)
F_TILE = np.float32(TILE_SIZE)
F_ALPHA_MAX = np.float32(ALPHA_MAX)
F_ALPHA_MIN = np.float32(ALPHA_MIN)
F_T_MIN = np.float32(T_MIN)
TS = TILE_SIZE
NP = TS * TS  # pixels of a tile
# Columns of a tile row evaluated together: one vector of float32 lanes of the compile target
# (16 with AVX-512, 8 with AVX2). A Gaussian visits only the blocks its column span reaches;
# the per-pixel tests reject everything outside it anyway, so the results do not depend on RB.
RB = min(vector_lanes(), TS)
if RB < TS:
    allow_short_vector_loops()  # the RB = 8 loops of the backward pass need it (ftgspp.runtime.jit)
_RB = np.uint64(RB)
_TSU = np.uint64(TS)

# Span culling margins (float64 maths, per Gaussian). The float32 quadratic form differs from
# the exact one by at most ~7 roundings (6e-8 each) of S = a dx^2 + c dy^2 + 2|b dx dy|, and
# S <= cond * q with cond <= (a + c)^2 / det; the ellipse is widened by 4 SPAN_REL cond, about
# ten times that. Gaussians whose conic is not positive definite, or too ill-conditioned for
# the bound (cond > 1.25e5), are evaluated on every row of their tiles.
SPAN_REL = 1e-6
SPAN_ABS = 1e-4  # absolute slack on q (exp and multiply rounding, float32 1/255)
SPAN_PX = 1e-3  # pixel slack on span end points
# Columns of the span table: whether every row must be visited; the centre; the extents of the
# widened ellipse q = a dx^2 + 2 b dx dy + c dy^2 <= lm (with the pixel slack); b, c, det and
# c lm, and the dx of its topmost point, for the row range over a tile's columns.
S_FULL, S_MX, S_MY, S_XR, S_YR, S_B, S_C, S_DET, S_CLM, S_XTOP = range(10)
N_SPAN = 10
PAIR_COST = 2.0  # load-balancing cost of a (tile, Gaussian) pair, in 16-pixel rows
MAX_TILE_LIST = 1 << 24  # Gaussians per tile: slots are kept in float32 tile state

# Columns of the per-pair gradient rows.
G_MX, G_MY, G_A, G_B, G_C, G_O, G_Z, G_COL = 0, 1, 2, 3, 4, 5, 6, 7

# The per-tile kernels are inlined into their parallel kernels (``_TILE_JIT``), never compiled
# on their own. As ordinary callees, Numba compiled them twice: standalone, and as a copy
# linked into ``render_forward`` / ``render_backward``. A process loading the cache runs the
# linked copy. In the process that compiled them, the JIT linker bound the call to the
# standalone copy (the first definition of the symbol), whose machine code was much slower
# (why inside LLVM was not isolated): that process ran the rasterizer 5-6x slower, forward
# plus backward (``ftgspp bench render`` times both kinds of process).
_TILE_JIT = dict(inline="always", **JIT)

# exp on [-8, 0]: Cephes' expf polynomial after power = n ln2 + r, |r| <= ln2 / 2.
_LOG2E = np.float32(1.44269504088896341)
_LN2_HI = np.float32(0.693359375)
_LN2_LO = np.float32(-2.12194440e-4)
_EXP_LO = np.float32(-8.0)  # exp(-8) < 1/255: below it every alpha is rejected anyway
_BIAS = np.float32(127.0)  # float32 exponent bias
_MANTISSA = np.float32(1 << 23)  # one unit of the exponent field
_P0, _P1, _P2, _P3, _P4, _P5 = (
    np.float32(c) for c in (1.9875691500e-4, 1.3981999507e-3, 8.3334519073e-3, 4.1665795894e-2, 1.6666665459e-1, 5.0000001201e-1)
)  # fmt: skip


class Binning(NamedTuple):
    """Output of ``bin_gaussians``."""

    offsets: np.ndarray  # [n_tiles + 1] int64, each tile's range in pair_gauss
    pair_gauss: np.ndarray  # [P] int32, Gaussian of each (tile, Gaussian) pair, grouped by tile
    span: np.ndarray  # [N, N_SPAN] float64, span table (columns S_*)
    tile_cost: np.ndarray  # [n_tiles] float64, estimated work in 16-pixel rows (load balancing)
    rect: np.ndarray  # [N, 4] int64, tile range tx0, tx1, ty0, ty1 (empty when culled)
    gauss_off: np.ndarray  # [N + 1] int64, offsets of each Gaussian's pairs (raster tile order)


class Forward(NamedTuple):
    """Output of ``render_forward``."""

    image: np.ndarray  # [H, W, D] float32
    alpha: np.ndarray  # [H, W] float32
    depth: np.ndarray  # [H, W] float32
    t_final: np.ndarray  # [H, W] float32, final transmittance
    stop_slot: np.ndarray  # [H, W] int32, slot of the Gaussian that stopped the pixel (else list length)
    n_used: np.ndarray  # [n_tiles] int64, slots composited before every pixel of the tile stopped
    pair_live: np.ndarray  # [P] uint8, 1 where the sorted pair contributed to some pixel
    pair_box: np.ndarray  # [P, 4] int64, each sorted pair's image rows [r0, r1) (``_row_range``) and
    # blocks of RB columns [b0, b1) (``_column_blocks``; (0, 1) when RB = 16) that it visits
    gauss_pairs: np.ndarray  # [P] int64, sorted pair index of each (Gaussian, tile), CSR by gauss_off
    tile_work: np.ndarray  # [n_tiles] float64, the backward pass's estimated work per tile


@intrinsic
def _f32_from_bits(typingctx, bits):
    """The float32 whose IEEE-754 bits are the int32 ``bits`` (a bit cast, no conversion)."""
    if bits != types.int32:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.FloatType())

    return types.float32(types.int32), codegen


@intrinsic
def _bits_of_f32(typingctx, x):
    """The int32 holding the IEEE-754 bits of the float32 ``x`` (a bit cast, no conversion)."""
    if x != types.float32:
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(32))

    return types.int32(types.float32), codegen


@njit(inline="always", **JIT)
def _kept(x, keep):
    """``x if keep else +0.0``, by a bit mask instead of a branch.

    Added to a tile-state row, the branch form became masked loads and stores in the
    vectorised pixel loop (the three colour rows shared one if/else), and a load after a
    masked store to the same address waits for that store to reach the cache: no
    store-to-load forwarding. The mask compiles to zero-masked multiplies and plain stores."""
    return _f32_from_bits(np.int32(_bits_of_f32(x) & -np.int32(keep)))


@njit(inline="always", **JIT)
def _pick(keep, a, b):
    """``a if keep else b`` (float32, bit for bit), by bit masks instead of a branch.

    The pixel loops update a tile-state row as a product or a sum with such a factor
    (``x * _pick(c, f, 1)``, ``x + _kept(d, c)``), not as ``new if c else x``: stored back to
    the row ``x`` was loaded from, a select (in either form) compiles to a masked store. That is
    a cheap k-masked move with AVX-512, but AVX2's ``vmaskmovps`` store was slow on this
    project's AMD EPYC (docs/benchmarks-history.md, 2026-11-30)."""
    m = -np.int32(keep)
    return _f32_from_bits(np.int32((_bits_of_f32(a) & m) | (_bits_of_f32(b) & ~m)))


@njit(**JIT)
def exp_clamped(power):
    """exp(power) for float32 ``power`` in [-8, 0], within 1 ulp; exp(-8) below, 1 above.

    Float32 arithmetic, plus one float-to-int32 conversion and a bit cast that build 2^n
    exactly from its exponent bits, so it vectorises and has the same bits on every machine. Below -8 any alpha is < 1/255 and rejected,
    and positive powers are rejected before their value is used.
    """
    x = min(max(power, _EXP_LO), F0)
    fn = np.floor(x * _LOG2E + F_HALF)  # n in [-12, 0]
    r = (x - fn * _LN2_HI) - fn * _LN2_LO
    p = _P0 * r + _P1
    p = p * r + _P2
    p = p * r + _P3
    p = p * r + _P4
    p = p * r + _P5
    p = p * (r * r) + r + F1
    # 2^n, n in [-12, 0], written as a float32's bits: biased exponent 127 + n, zero mantissa,
    # i.e. the integer (127 + n) 2^23, computed in float32 (exact) so that it vectorises as
    # one float-to-int32 conversion on AVX2 too
    return p * _f32_from_bits(np.int32((fn + _BIAS) * _MANTISSA))  # all exact in float32


# ------------------------------------------------------------------------------ binning


@njit(parallel=True, **JIT)
def bin_gaussians(
    means2d: np.ndarray,  # [N, 2] float32
    conics: np.ndarray,  # [N, 3] float32
    opacities: np.ndarray,  # [N] float32
    radii: np.ndarray,  # [N, 2] int64
    width: int,
    height: int,
):
    """Tile lists, span table and the bookkeeping of the later passes (see ``Binning``).

    The per-Gaussian work runs in parallel; the counting sort that groups the pairs by
    tile is serial, so the lists are the same for any thread count."""
    n = means2d.shape[0]
    tiles_x = (width + TS - 1) // TS
    tiles_y = (height + TS - 1) // TS
    n_tiles = tiles_x * tiles_y
    ftx = np.float32(tiles_x)
    fty = np.float32(tiles_y)
    rect = np.zeros((n, 4), np.int64)  # tx0, tx1, ty0, ty1 (empty: tx0 == tx1)
    span = np.zeros((n, N_SPAN), np.float64)
    cost = np.zeros(n, np.float64)  # estimated cost of each of the Gaussian's pairs
    for k in prange(n):
        o = opacities[k]
        mx = means2d[k, 0]
        my = means2d[k, 1]
        culled = radii[k, 0] <= 0 or radii[k, 1] <= 0
        if culled or not (o >= F_ALPHA_MIN) or not (np.isfinite(mx) and np.isfinite(my)):
            continue  # culled, or alpha <= o < 1/255 everywhere
        # tile range in gsplat's pixel coordinates and rounding order (IntersectTile.cu)
        cx = (mx + F_HALF) / F_TILE
        cy = (my + F_HALF) / F_TILE
        rx = np.float32(radii[k, 0]) / F_TILE
        ry = np.float32(radii[k, 1]) / F_TILE
        tx0 = min(max(np.floor(cx - rx), F0), ftx)
        tx1 = min(max(np.ceil(cx + rx), F0), ftx)
        ty0 = min(max(np.floor(cy - ry), F0), fty)
        ty1 = min(max(np.ceil(cy + ry), F0), fty)
        if tx1 <= tx0 or ty1 <= ty0:
            continue
        rect[k, 0] = np.int64(tx0)
        rect[k, 1] = np.int64(tx1)
        rect[k, 2] = np.int64(ty0)
        rect[k, 3] = np.int64(ty1)
        a = np.float64(conics[k, 0])
        b = np.float64(conics[k, 1])
        c = np.float64(conics[k, 2])
        det = a * c - b * b
        span[k, S_FULL] = 1.0  # every tile row, unless the ellipse bound is safe
        span[k, S_MX] = mx
        span[k, S_MY] = my
        cost[k] = PAIR_COST + TS
        if a > 0.0 and c > 0.0 and det > 0.0 and np.isfinite(det):
            cond = (a + c) * (a + c) / det
            shrink = 1.0 - 4.0 * SPAN_REL * cond
            if shrink > 0.5:
                lim = 2.0 * math.log(np.float64(o) / np.float64(F_ALPHA_MIN))
                lm = (lim + SPAN_ABS) / shrink
                span[k, S_FULL] = 0.0
                y_extent = math.sqrt(a * lm / det)
                span[k, S_YR] = y_extent + SPAN_PX
                span[k, S_XR] = math.sqrt(c * lm / det) + SPAN_PX
                span[k, S_B] = b
                span[k, S_C] = c
                span[k, S_DET] = det
                span[k, S_CLM] = c * lm
                span[k, S_XTOP] = -b * y_extent / a  # where a dx + b dy = 0 at dy = y_extent
                cost[k] = PAIR_COST + min(TS, 2.0 * span[k, S_YR] + 1.0)
    offsets = np.zeros(n_tiles + 1, np.int64)
    gauss_off = np.zeros(n + 1, np.int64)  # CSR of each Gaussian's pairs, in tile order
    for k in range(n):
        gauss_off[k + 1] = gauss_off[k] + (rect[k, 1] - rect[k, 0]) * (rect[k, 3] - rect[k, 2])
        for ty in range(rect[k, 2], rect[k, 3]):
            for tx in range(rect[k, 0], rect[k, 1]):
                offsets[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        offsets[t + 1] += offsets[t]
    fill = offsets[:n_tiles].copy()
    pair_gauss = np.empty(offsets[n_tiles], np.int32)
    tile_cost = np.zeros(n_tiles, np.float64)
    for k in range(n):
        for ty in range(rect[k, 2], rect[k, 3]):
            for tx in range(rect[k, 0], rect[k, 1]):
                t = ty * tiles_x + tx
                pair_gauss[fill[t]] = k
                fill[t] += 1
                tile_cost[t] += cost[k]
    return Binning(offsets, pair_gauss, span, tile_cost, rect, gauss_off)


@njit(**JIT)
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


@njit(inline="always", **JIT)
def _row_range(span: np.ndarray, g: int, x0: int, x1: int, y0: int, y1: int):
    """Rows [r0, r1) of the tile rows [y0, y1) that may hold pixels of Gaussian g in the tile
    columns [x0, x1): the rows the widened ellipse crosses within those columns (empty when it
    misses them).

    The ellipse cut by a band of columns is convex, so its rows are one interval: from the
    lowest to the highest point of the ellipse over the band's pixel columns [cl, ch]. The
    highest is the ellipse's top, at dx = x_top, when the band holds it, else the upper arc
    y(dx) = (-b dx + sqrt(c lm - det dx^2)) / c at the band's end nearest x_top (the arc is
    concave); the lowest mirrors it (bottom at -x_top). Rounding in these float64 steps is
    orders of magnitude below the pixel slack added to both ends.

    Every case is computed and the answer selected, without branches: which case holds is
    unpredictable from pair to pair, and the mispredicted branches of the plain form cost
    more than the arithmetic (a tenth of ``render_forward`` on a quick run's views). The
    values selected are those of the plain form's expressions, in the same order.
    """
    full = span[g, S_FULL] != 0.0
    mx = span[g, S_MX]
    xr = span[g, S_XR]
    cl = max(np.float64(x0), np.ceil(mx - xr))  # the band's pixel columns inside the x extent
    ch = min(np.float64(x1 - 1), np.floor(mx + xr))
    da = cl - mx
    db = ch - mx
    b = span[g, S_B]
    c = span[g, S_C]
    det = span[g, S_DET]
    clm = span[g, S_CLM]
    xt = span[g, S_XTOP]
    yr = span[g, S_YR]
    d_up = da if xt < da else db
    up_arc = (-b * d_up + math.sqrt(max(clm - det * d_up * d_up, 0.0))) / c + SPAN_PX
    up = yr if (da <= xt) & (xt <= db) else up_arc
    d_down = da if -xt < da else db
    down_arc = (b * d_down + math.sqrt(max(clm - det * d_down * d_down, 0.0))) / c + SPAN_PX
    down = yr if (da <= -xt) & (-xt <= db) else down_arc
    my = span[g, S_MY]
    r0 = max(np.float64(y0), np.ceil(my - down))
    r1 = min(np.float64(y1 - 1), np.floor(my + up))
    empty = (ch < cl) | (r1 < r0)
    # a Gaussian without a safe span (its other columns are zeros) visits every row
    r0 = np.float64(y0) if full else (0.0 if empty else r0)
    r1 = np.float64(y1 - 1) if full else (-1.0 if empty else r1)
    return np.int64(r0), np.int64(r1) + 1


@njit(**JIT)
def _column_blocks(span: np.ndarray, g: int, x0: int, rb: int):
    """Blocks [b0, b1) of ``rb`` columns of the tile starting at column ``x0`` that may hold
    pixels of Gaussian g (every block without a safe span; none when it misses the tile)."""
    if span[g, S_FULL] != 0.0:
        return 0, TS // rb
    mx = span[g, S_MX]
    xr = span[g, S_XR]
    lo = max(np.float64(x0), np.ceil(mx - xr))
    hi = min(np.float64(x0 + TS - 1), np.floor(mx + xr))
    if hi < lo:
        return 0, 0
    return (np.int64(lo) - x0) // rb, (np.int64(hi) - x0) // rb + 1


@njit(inline="always", **JIT)
def _pair_blocks(pair_box: np.ndarray, q: int):
    """Column blocks [b0, b1) of sorted pair ``q`` (``Forward.pair_box``): with 16 lanes the
    constants (0, 1), one block, which every pair with rows reaches, so that the column loops
    compile to fixed 16-column code; otherwise the table's."""
    if RB == TS:
        return 0, 1
    return pair_box[q, 2], pair_box[q, 3]


# ------------------------------------------------------------------------------ forward

# Rows of a tile's float32 state in the forward pass: one flat array, offsets known at
# compile time, so the compiler sees that the rows never overlap and vectorises the pixel
# loops without runtime checks. Pixel p = row * TS + column.
_F_T = np.uint64(0 * NP)  # transmittance; 0 marks a stopped pixel (outside the image: from the start)
_F_TSTOP = np.uint64(1 * NP)  # transmittance of a stopped pixel
_F_SLOT = np.uint64(2 * NP)  # slot of the Gaussian that stopped it, else the list length (exact: < MAX_TILE_LIST)
_F_W = np.uint64(3 * NP)  # weight alpha T of the Gaussian being composited (0: none)
_F_Z = np.uint64(4 * NP)  # accumulated depth
_F_PX = np.uint64(5 * NP)  # pixel coordinates
_F_PY = np.uint64(6 * NP)
_F_ACC = 7  # accumulated colour, one row per channel
_F_ACC0, _F_ACC1, _F_ACC2 = np.uint64(7 * NP), np.uint64(8 * NP), np.uint64(9 * NP)


@njit(inline="always", **JIT)
def _forward_step(t, dx, dy, nh_a, nh_c, cb, op):
    """One Gaussian on one pixel of transmittance ``t`` (0: stopped) at offset (dx, dy).

    Returns its weight alpha T (0 unless it contributes), the new transmittance (0 when it
    stops the pixel), whether it stops the pixel and whether it contributes."""
    power = nh_a * dx * dx + nh_c * dy * dy - cb * dy * dx
    al = min(op * exp_clamped(power), F_ALPHA_MAX)
    live = (t > F0) & (power <= F0) & (al >= F_ALPHA_MIN)
    t_next = t * (F1 - al)
    stop = live & (t_next <= F_T_MIN)
    use = live & (t_next > F_T_MIN)
    w = al * t if use else F0
    t_new = t_next if use else (F0 if stop else t)
    return w, t_new, stop, use


@njit(inline="always", **JIT)
def _forward_pixel(st, p, mx, my, nh_a, nh_c, cb, op, z, f_slot):
    """``_forward_step`` on pixel ``p`` of the tile state: updates its transmittance, stop
    record and depth; returns the weight and whether the Gaussian stopped or contributed."""
    t = st[_F_T + p]
    w, t_new, stop, use = _forward_step(t, st[_F_PX + p] - mx, st[_F_PY + p] - my, nh_a, nh_c, cb, op)
    st[_F_T + p] = t_new
    # A pixel stops at most once (then t = 0), and until then its stop record holds 1 and
    # the list length (integers < 2^24, exact in float32): x 1 and + 0 keep them, x t and
    # + (slot - length) set them, exactly. Stores of these products, unlike the select's,
    # stay plain stores on AVX2 (see ``_pick``).
    st[_F_TSTOP + p] *= _pick(stop, t, F1)
    st[_F_SLOT + p] += _kept(f_slot - st[_F_SLOT + p], stop)
    st[_F_Z + p] += _kept(w * z, use)
    return w, stop, use


@njit(inline="always", **JIT)
def _forward_pixel_rgb(st, p, mx, my, nh_a, nh_c, cb, op, z, f_slot, c0, c1, c2):
    """``_forward_pixel`` plus the pixel's RGB accumulation; returns (stopped, contributed)."""
    w, stop, use = _forward_pixel(st, p, mx, my, nh_a, nh_c, cb, op, z, f_slot)
    st[_F_ACC0 + p] += _kept(w * c0, use)
    st[_F_ACC1 + p] += _kept(w * c1, use)
    st[_F_ACC2 + p] += _kept(w * c2, use)
    return stop, use


@njit(inline="always", **JIT)
def _sort_by_depth(ids, depth_keys):
    """``ids`` (a tile's Gaussians, equal depths in increasing index order, as ``bin_gaussians``
    lists them and this sort leaves them) in increasing ``depth_keys`` order, ties by index.

    A stable least-significant-digit radix sort on the 32-bit keys, one byte per pass, a pass
    skipped when every key has the same byte there (the high bytes of nearby depths): the
    same order as sorting ``(key << 32) | index``, in a few linear passes instead of a
    comparison sort's n log n steps with unpredictable branches."""
    n = ids.shape[0]
    a = ids.copy()
    ka = np.empty(n, np.uint32)
    for i in range(n):
        ka[i] = depth_keys[a[i]]
    b = np.empty_like(a)
    kb = np.empty(n, np.uint32)
    counts = np.empty(256, np.int64)
    for shift in range(0, 32, 8):
        sh = np.uint32(shift)
        counts[:] = 0
        for i in range(n):
            counts[(ka[i] >> sh) & np.uint32(255)] += 1
        if n == 0 or counts[(ka[0] >> sh) & np.uint32(255)] == n:
            continue  # one byte value: the pass would keep the order
        total = 0
        for d in range(256):
            c = counts[d]
            counts[d] = total
            total += c
        for i in range(n):
            d = (ka[i] >> sh) & np.uint32(255)
            j = counts[d]
            counts[d] = j + 1
            b[j] = a[i]
            kb[j] = ka[i]
        a, b = b, a
        ka, kb = kb, ka
    return a


@njit(**_TILE_JIT)
def _forward_tile(
    tile, means2d, conics, colors, opacities, depths, depth_keys, background, offsets, pair_gauss,
    span, rect, gauss_off, gauss_pairs, n_used, pair_live, pair_box, image, alpha_out, depth_out, t_final,
    stop_slot,
):  # fmt: skip
    """Sort one tile's list by depth, composite it into the outputs and note where each of
    its pairs landed in ``gauss_pairs`` (per-Gaussian CSR) and whether it contributed.
    Returns the tile's backward load estimate (rows of the contributing pairs)."""
    height, width = t_final.shape
    n_dim = colors.shape[1]
    tiles_x = (width + TS - 1) // TS
    start = offsets[tile]
    count = offsets[tile + 1] - start
    order = _sort_by_depth(pair_gauss[start : start + count], depth_keys)
    tx = tile % tiles_x
    ty = tile // tiles_x
    for i in range(count):
        g = np.int64(order[i])
        pair_gauss[start + i] = g
        local = (ty - rect[g, 2]) * (rect[g, 1] - rect[g, 0]) + (tx - rect[g, 0])
        gauss_pairs[gauss_off[g] + local] = start + i

    x0 = tx * TS
    y0 = ty * TS
    x1 = min(x0 + TS, width)
    y1 = min(y0 + TS, height)
    st = np.zeros((_F_ACC + n_dim) * NP, np.float32)
    for p in range(np.uint64(NP)):
        st[_F_TSTOP + p] = F1
        st[_F_SLOT + p] = -F1  # outside the image: never stopped by any slot
        st[_F_PX + p] = np.float32(x0 + p % TS)
        st[_F_PY + p] = np.float32(y0 + p // TS)
    for row in range(y1 - y0):
        for col in range(x1 - x0):
            p = np.uint64(row * TS + col)
            st[_F_T + p] = F1
            st[_F_SLOT + p] = np.float32(count)
    active = (x1 - x0) * (y1 - y0)
    rows = 0.0
    used = count
    # Every pair's rows and column blocks first, in a loop of independent iterations: computed
    # inside the compositing loops (here and in the backward pass), this float64 maths would sit
    # on their critical path for every pair.
    for i in range(count):
        pair_live[start + i] = 0
        g = pair_gauss[start + i]
        r0, r1 = _row_range(span, g, x0, x1, y0, y1)
        if RB == TS:  # one block, which the rows reach when there are any
            b0, b1 = 0, 1
        else:
            b0, b1 = _column_blocks(span, g, x0, RB)
        pair_box[start + i, 0] = r0
        pair_box[start + i, 1] = r1
        pair_box[start + i, 2] = b0
        pair_box[start + i, 3] = b1
    for i in range(count):
        if active == 0:  # every pixel has stopped
            used = i
            break
        g = pair_gauss[start + i]
        r0 = pair_box[start + i, 0]
        r1 = pair_box[start + i, 1]
        if r1 <= r0:  # misses the tile's pixels
            continue
        lo = np.uint64((r0 - y0) * TS)
        hi = np.uint64((r1 - y0) * TS)
        b0, b1 = _pair_blocks(pair_box, start + i)
        mx = means2d[g, 0]
        my = means2d[g, 1]
        nh_a = -F_HALF * conics[g, 0]
        nh_c = -F_HALF * conics[g, 2]
        cb = conics[g, 1]
        op = opacities[g]
        z = depths[g]
        f_slot = np.float32(i)
        # Boolean OR reductions in the pixel loops: Numba widens integer sums to 64 bits, whose
        # lanes make LLVM pick 4-wide vectors on AVX2 (a float sum would not vectorise at all).
        stops = False
        uses = False
        if n_dim == 3:
            c0 = colors[g, 0]
            c1 = colors[g, 1]
            c2 = colors[g, 2]
            if RB == TS:  # whole rows: one loop over them all (what LLVM vectorises best at 16 lanes)
                for p in range(lo, hi):  # branch-free: vectorised
                    stop, use = _forward_pixel_rgb(st, p, mx, my, nh_a, nh_c, cb, op, z, f_slot, c0, c1, c2)
                    stops |= stop
                    uses |= use
            else:
                for q in range(lo, hi, _TSU):
                    for b in range(b0, b1):
                        base = q + np.uint64(b * RB)
                        for j in range(_RB):  # branch-free: vectorised
                            stop, use = _forward_pixel_rgb(st, base + j, mx, my, nh_a, nh_c, cb, op, z, f_slot,
                                                           c0, c1, c2)
                            stops |= stop
                            uses |= use
        else:
            for q in range(lo, hi, _TSU):
                for b in range(b0, b1):
                    base = q + np.uint64(b * RB)
                    for j in range(_RB):  # branch-free: vectorised
                        p = base + j
                        w, stop, use = _forward_pixel(st, p, mx, my, nh_a, nh_c, cb, op, z, f_slot)
                        st[_F_W + p] = w
                        stops |= stop
                        uses |= use
            if uses:
                for ch in range(n_dim):
                    c = colors[g, ch]
                    acc = np.uint64((_F_ACC + ch) * NP)
                    for q in range(lo, hi, _TSU):
                        for b in range(b0, b1):
                            base = q + np.uint64(b * RB)
                            for j in range(_RB):
                                w = st[_F_W + base + j]
                                st[acc + base + j] += _kept(w * c, w > F0)
        if stops:  # count the pixels this Gaussian stopped (rare: once per pixel)
            for p in range(lo, hi):
                active -= np.int64(st[_F_SLOT + p] == f_slot)
        if uses:
            pair_live[start + i] = 1
            rows += PAIR_COST + (r1 - r0)
    n_used[tile] = used
    for py in range(y0, y1):
        for px in range(x0, x1):
            p = np.uint64((py - y0) * TS + (px - x0))
            t = st[_F_T + p]
            if t == F0:
                t = st[_F_TSTOP + p]
            for ch in range(n_dim):
                image[py, px, ch] = st[np.uint64((_F_ACC + ch) * NP) + p] + t * background[ch]
            alpha_out[py, px] = F1 - t
            depth_out[py, px] = st[_F_Z + p]
            t_final[py, px] = t
            stop_slot[py, px] = np.int32(st[_F_SLOT + p])
    return rows


@njit(parallel=True, **JIT)
def render_forward(
    means2d: np.ndarray,  # [N, 2] float32
    conics: np.ndarray,  # [N, 3] float32
    colors: np.ndarray,  # [N, D] float32
    opacities: np.ndarray,  # [N] float32
    depths: np.ndarray,  # [N] float32
    depth_keys: np.ndarray,  # [N] uint32, order-preserving bits of depth
    background: np.ndarray,  # [D] float32
    offsets: np.ndarray,  # [n_tiles + 1] int64
    pair_gauss: np.ndarray,  # [P] int32, index order per tile (bin_gaussians'); sorted in place by (depth, index)
    span: np.ndarray,  # [N, N_SPAN] float64
    rect: np.ndarray,  # [N, 4] int64
    gauss_off: np.ndarray,  # [N + 1] int64
    worker_offsets: np.ndarray,  # [W + 1] int64
    worker_tiles: np.ndarray,  # [n_tiles] int64
    width: int,
    height: int,
):
    """Composite every tile (see ``Forward``); sorts ``pair_gauss`` in place per tile."""
    n_tiles = offsets.shape[0] - 1
    n_dim = colors.shape[1]
    image = np.empty((height, width, n_dim), np.float32)
    alpha = np.empty((height, width), np.float32)
    depth = np.empty((height, width), np.float32)
    t_final = np.empty((height, width), np.float32)
    stop_slot = np.empty((height, width), np.int32)
    n_used = np.empty(n_tiles, np.int64)
    pair_live = np.empty(pair_gauss.shape[0], np.uint8)
    pair_box = np.empty((pair_gauss.shape[0], 4), np.int64)
    gauss_pairs = np.empty(pair_gauss.shape[0], np.int64)
    work = np.zeros(n_tiles, np.float64)
    for w in prange(worker_offsets.shape[0] - 1):
        for j in range(worker_offsets[w], worker_offsets[w + 1]):
            tile = worker_tiles[j]
            work[tile] = _forward_tile(
                tile, means2d, conics, colors, opacities, depths, depth_keys, background, offsets,
                pair_gauss, span, rect, gauss_off, gauss_pairs, n_used, pair_live, pair_box, image, alpha, depth,
                t_final, stop_slot,
            )  # fmt: skip
    return Forward(image, alpha, depth, t_final, stop_slot, n_used, pair_live, pair_box, gauss_pairs, work)


# ----------------------------------------------------------------------------- backward

# Rows of the backward pass's float32 tile state (as in the forward pass).
_B_T = np.uint64(0 * NP)  # transmittance after the slot being visited
_B_REST = np.uint64(1 * NP)  # rest_i (see _backward_tile)
_B_SLOT = np.uint64(2 * NP)  # stop slot; 0 outside the image, so nothing contributes there
_B_GZ = np.uint64(3 * NP)  # depth cotangent
_B_DOT = np.uint64(4 * NP)  # <colour cotangent, colour> of the Gaussian visited, then its weight (D != 3)
_B_PX = np.uint64(5 * NP)
_B_PY = np.uint64(6 * NP)
_B_G = 7  # colour cotangent, one row per channel
_B_G0, _B_G1, _B_G2 = np.uint64(7 * NP), np.uint64(8 * NP), np.uint64(9 * NP)
# Per-column sums of one Gaussian's per-pixel terms: dL/dpower times dx, dy, dx^2, dx dy,
# dy^2; dL/dopacity; g_z w; then g_channel w per channel.
N_TERMS = 7
_L = tuple(np.uint64(k * TS) for k in range(N_TERMS + 3))


@njit(inline="always", **JIT)
def _backward_step(t_after, rest, dx, dy, dot, before_stop, nh_a, nh_c, cb, op):
    """The forward step recomputed on one pixel, walking back (same code, same bits).

    Returns whether the Gaussian contributed there, its weight, the pixel's transmittance
    before it, the new rest, and dL/dpower and dL/dopacity (0 where it has none, or where
    alpha is clamped)."""
    power = nh_a * dx * dx + nh_c * dy * dy - cb * dy * dx
    gauss = exp_clamped(power)
    raw = op * gauss
    al = min(raw, F_ALPHA_MAX)
    live = (power <= F0) & (al >= F_ALPHA_MIN) & before_stop
    inv_one_minus = F1 / (F1 - al)
    t = t_after * inv_one_minus
    w = al * t
    d_alpha = t * dot - rest * inv_one_minus
    grad = live & (raw <= F_ALPHA_MAX)
    d_power = d_alpha * raw if grad else F0
    d_opacity = d_alpha * gauss if grad else F0
    # t_after x 1 is t_after; rest + 0 is rest (a zero rest may lose its sign, which no
    # output keeps: it only multiplies into terms added to sums that start at +0)
    t_new = t_after * _pick(live, inv_one_minus, F1)
    rest_new = rest + _kept(w * dot, live)
    return live, w, t_new, rest_new, d_power, d_opacity


@njit(inline="always", **JIT)
def _backward_pixel(st, lanes, p, j, gz, dot, mx, my, nh_a, nh_c, cb, op, f_slot):
    """``_backward_step`` on pixel ``p`` (column ``j``) of the tile state: updates its
    transmittance and rest, adds its moment terms to column ``j`` of the per-column sums;
    returns whether the Gaussian contributed there and its weight."""
    dx = st[_B_PX + p] - mx
    dy = st[_B_PY + p] - my
    live, w, t_new, rest_new, d_power, d_opacity = _backward_step(
        st[_B_T + p], st[_B_REST + p], dx, dy, dot, f_slot < st[_B_SLOT + p], nh_a, nh_c, cb, op
    )
    st[_B_T + p] = t_new
    st[_B_REST + p] = rest_new
    lanes[_L[0] + j] += d_power * dx
    lanes[_L[1] + j] += d_power * dy
    lanes[_L[2] + j] += d_power * dx * dx
    lanes[_L[3] + j] += d_power * dx * dy
    lanes[_L[4] + j] += d_power * dy * dy
    lanes[_L[5] + j] += d_opacity
    lanes[_L[6] + j] += _kept(gz * w, live)
    return live, w


@njit(inline="always", **JIT)
def _backward_block3(st, lanes, lo, hi, base, z, c0, c1, c2, mx, my, nh_a, nh_c, cb, op, f_slot):
    """``_backward_pixel`` on the ``RB`` columns from ``base`` of the tile rows [lo, hi) for an
    RGB Gaussian, adding its colour terms as well (rows in order: the per-column sums keep
    their order)."""
    for q in range(lo, hi, _TSU):
        for k in range(_RB):  # branch-free: vectorised
            j = base + k
            p = q + j
            gz = st[_B_GZ + p]
            g0 = st[_B_G0 + p]
            g1 = st[_B_G1 + p]
            g2 = st[_B_G2 + p]
            dot = gz * z + (g0 * c0 + g1 * c1 + g2 * c2)
            live, w = _backward_pixel(st, lanes, p, j, gz, dot, mx, my, nh_a, nh_c, cb, op, f_slot)
            lanes[_L[7] + j] += _kept(g0 * w, live)
            lanes[_L[8] + j] += _kept(g1 * w, live)
            lanes[_L[9] + j] += _kept(g2 * w, live)


@njit(**_TILE_JIT)
def _backward_tile(
    tile, means2d, conics, colors, opacities, depths, background, offsets, pair_gauss, n_used,
    pair_live, pair_box, t_final, stop_slot, grad_image, grad_alpha, grad_depth, pair_grads, bg_grads,
):  # fmt: skip
    """Walk one tile's list back to front; write its gradient rows and its background
    gradient.

    With w_i = alpha_i T_i and <g, f_i> the output cotangent dotted with Gaussian i's
    colour and depth, dL/dalpha_i = T_i <g, f_i> - rest_i / (1 - alpha_i), where
    rest_i = sum_{j > i} w_j <g, f_j> + T_final (<g_image, background> - g_alpha).
    T_i is recovered from T_final as T_{i+1} / (1 - alpha_i). A Gaussian's per-pixel terms
    are summed per pixel column over its rows (float32, at most 16 terms), then over the
    tile's columns in order in float64 (a column it does not visit holds +0.0, and adding +0.0
    to a sum that starts at +0.0 changes no bit).
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
    st = np.zeros((_B_G + n_dim) * NP, np.float32)
    for p in range(np.uint64(NP)):
        st[_B_PX + p] = np.float32(x0 + p % TS)
        st[_B_PY + p] = np.float32(y0 + p // TS)
    for ch in range(n_dim):
        bg_grads[tile, ch] = 0.0
    for py in range(y0, y1):
        for px in range(x0, x1):
            p = np.uint64((py - y0) * TS + (px - x0))
            t = t_final[py, px]
            st[_B_T + p] = t
            st[_B_SLOT + p] = np.float32(stop_slot[py, px])
            dot_bg = F0
            for ch in range(n_dim):
                gc = grad_image[py, px, ch]
                st[np.uint64((_B_G + ch) * NP) + p] = gc
                dot_bg += gc * background[ch]
                bg_grads[tile, ch] += np.float64(gc * t)
            st[_B_GZ + p] = grad_depth[py, px]
            st[_B_REST + p] = t * dot_bg - grad_alpha[py, px] * t
    n_terms = N_TERMS + n_dim
    lanes = np.empty(n_terms * TS, np.float32)
    lanes64 = np.empty(n_terms * TS, np.float64)
    lanes[:] = F0
    sums = np.empty(n_terms, np.float64)
    used = n_used[tile]
    for i in range(count - 1, used - 1, -1):  # composited after every pixel had stopped
        pair_grads[start + i, :] = 0.0
    for i in range(used - 1, -1, -1):
        if pair_live[start + i] == 0:  # no pixel saw it: no gradient
            pair_grads[start + i, :] = 0.0
            continue
        g = pair_gauss[start + i]
        r0 = pair_box[start + i, 0]
        r1 = pair_box[start + i, 1]
        lo = np.uint64((r0 - y0) * TS)
        hi = np.uint64((r1 - y0) * TS)
        b0, b1 = _pair_blocks(pair_box, start + i)
        mx = means2d[g, 0]
        my = means2d[g, 1]
        nh_a = -F_HALF * conics[g, 0]
        nh_c = -F_HALF * conics[g, 2]
        cb = conics[g, 1]
        op = opacities[g]
        z = depths[g]
        f_slot = np.float32(i)
        if n_dim == 3:
            c0 = colors[g, 0]
            c1 = colors[g, 1]
            c2 = colors[g, 2]
            # one block at a time over all rows, each at a constant column offset, so a loop
            # carries 10 vectors of column sums (one block's), not 20 (the RB = 8 case)
            if b0 <= 0 < b1:
                _backward_block3(st, lanes, lo, hi, np.uint64(0), z, c0, c1, c2, mx, my, nh_a, nh_c, cb, op, f_slot)
            if TS // RB > 1 and b0 <= 1 < b1:
                _backward_block3(st, lanes, lo, hi, _RB, z, c0, c1, c2, mx, my, nh_a, nh_c, cb, op, f_slot)
        else:
            for p in range(lo, hi):
                st[_B_DOT + p] = F0
            for ch in range(n_dim):
                c = colors[g, ch]
                gch = np.uint64((_B_G + ch) * NP)
                for p in range(lo, hi):
                    st[_B_DOT + p] += st[gch + p] * c
            for q in range(lo, hi, _TSU):
                for b in range(b0, b1):
                    base = np.uint64(b * RB)
                    for k in range(_RB):  # branch-free: vectorised
                        j = base + k
                        p = q + j
                        gz = st[_B_GZ + p]
                        dot = gz * z + st[_B_DOT + p]
                        live, w = _backward_pixel(st, lanes, p, j, gz, dot, mx, my, nh_a, nh_c, cb, op, f_slot)
                        st[_B_DOT + p] = w if live else F0
                    for ch in range(n_dim):
                        gch = np.uint64((_B_G + ch) * NP)
                        lane = np.uint64((N_TERMS + ch) * TS)
                        for k in range(_RB):
                            j = base + k
                            w = st[_B_DOT + q + j]
                            lanes[lane + j] += _kept(st[gch + q + j] * w, w > F0)
        # widened in one vectorised pass (exact), then summed in column order: the same sums
        # as widening each term in the loop, without one scalar conversion per term
        for q in range(n_terms * TS):
            lanes64[q] = np.float64(lanes[q])
            lanes[q] = F0  # for the next pair
        for k in range(n_terms):
            s = 0.0
            for j in range(TS):  # all columns, a fixed count: unvisited ones hold +0, a no-op here
                s += lanes64[k * TS + j]
            sums[k] = s
        out = pair_grads[start + i]
        # power = -0.5 (a dx^2 + c dy^2) - b dx dy, dx = px - mx, dy = py - my
        ca = np.float64(conics[g, 0])
        cbd = np.float64(conics[g, 1])
        cc = np.float64(conics[g, 2])
        out[G_MX] = ca * sums[0] + cbd * sums[1]
        out[G_MY] = cc * sums[1] + cbd * sums[0]
        out[G_A] = -0.5 * sums[2]
        out[G_B] = -sums[3]
        out[G_C] = -0.5 * sums[4]
        out[G_O] = sums[5]
        out[G_Z] = sums[6]
        for ch in range(n_dim):
            out[G_COL + ch] = sums[N_TERMS + ch]


@njit(parallel=True, **JIT)
def render_backward(
    means2d: np.ndarray,  # [N, 2] float32
    conics: np.ndarray,  # [N, 3] float32
    colors: np.ndarray,  # [N, D] float32
    opacities: np.ndarray,  # [N] float32
    depths: np.ndarray,  # [N] float32
    background: np.ndarray,  # [D] float32
    offsets: np.ndarray,  # [n_tiles + 1] int64
    pair_gauss: np.ndarray,  # [P] int32, as sorted by render_forward
    n_used: np.ndarray,  # [n_tiles] int64, from render_forward
    pair_live: np.ndarray,  # [P] uint8, from render_forward
    pair_box: np.ndarray,  # [P, 4] int64, from render_forward
    worker_offsets: np.ndarray,  # [W + 1] int64
    worker_tiles: np.ndarray,  # [n_tiles] int64
    t_final: np.ndarray,  # [H, W] float32
    stop_slot: np.ndarray,  # [H, W] int32
    grad_image: np.ndarray,  # [H, W, D] float32
    grad_alpha: np.ndarray,  # [H, W] float32
    grad_depth: np.ndarray,  # [H, W] float32
):
    """Per-(tile, slot) gradient rows [P, 7 + D] float32 (columns G_*; float64 sums rounded
    once) and per-tile background gradients [n_tiles, D] float64."""
    n_dim = colors.shape[1]
    pair_grads = np.empty((pair_gauss.shape[0], G_COL + n_dim), np.float32)
    bg_grads = np.empty((offsets.shape[0] - 1, n_dim), np.float64)
    for w in prange(worker_offsets.shape[0] - 1):
        for j in range(worker_offsets[w], worker_offsets[w + 1]):
            _backward_tile(
                worker_tiles[j], means2d, conics, colors, opacities, depths, background, offsets,
                pair_gauss, n_used, pair_live, pair_box, t_final, stop_slot, grad_image, grad_alpha, grad_depth,
                pair_grads, bg_grads,
            )  # fmt: skip
    return pair_grads, bg_grads


@njit(parallel=True, **JIT)
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
