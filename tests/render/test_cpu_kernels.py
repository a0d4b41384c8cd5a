"""Pieces of the ``cpu`` rasterizer's Numba kernels: depth sort keys and each tile's depth
sort, the clamped exp, the tile balancing, the tile-list limit, and compiled vs cache-loaded
kernels (same bits)."""

from __future__ import annotations

import numpy as np
import pytest

from ftgspp.render import cpu
from ftgspp.render.contract import ALPHA_MIN
from tests.render.cpu_scenes import make_scene, run


def test_depth_sort_keys_order_floats() -> None:
    depths = np.array([3.0, -2.0, 0.0, -0.0, 1e-30, -1e30, 7.5, 3.0], np.float32)
    keys = cpu.depth_sort_keys(depths)
    order = np.lexsort((np.arange(len(depths)), keys))
    assert list(order) == list(np.lexsort((np.arange(len(depths)), depths + 0.0)))


@pytest.mark.parametrize("spread", [4, 1 << 12, 1 << 31])  # many ties, some, few (bytes of every rank)
def test_a_tiles_depth_sort_is_by_depth_then_index(spread: int) -> None:
    rng = np.random.default_rng(spread)
    depth_keys = rng.integers(0, spread, 3000).astype(np.uint32) | np.uint32(0x80000000)
    for n in (0, 1, 2, 17, 300, 3000):
        ids = np.sort(rng.choice(3000, n, replace=False)).astype(np.int32)  # a tile list: index order
        got = cpu._k._sort_by_depth(ids, depth_keys)
        want = ids[np.lexsort((ids, depth_keys[ids]))]  # (depth, index), as the old key sort
        assert got.dtype == ids.dtype and list(got) == list(want)
        assert list(cpu._k._sort_by_depth(got, depth_keys)) == list(want)  # a sorted list stays


def test_exp_clamped_is_within_one_ulp_of_exact_exp() -> None:
    """The kernels' own exp against float64 NumPy on [-8, 0]; below -8 it stays < 1/255."""
    x = np.concatenate([np.linspace(-8, 0, 400_001), -np.logspace(-12, np.log10(8), 20_001)]).astype(np.float32)
    got = np.array([cpu._k.exp_clamped(v) for v in x[::97]] + [cpu._k.exp_clamped(v) for v in x[-500:]], np.float32)
    want = np.exp(np.concatenate([x[::97], x[-500:]]).astype(np.float64))
    ulp = np.spacing(want.astype(np.float32)).astype(np.float64)
    assert np.max(np.abs(got - want) / ulp) <= 1.0
    assert cpu._k.exp_clamped(np.float32(0.0)) == 1.0
    for below in (-8.5, -30.0, -1e30):
        assert 0 < cpu._k.exp_clamped(np.float32(below)) < ALPHA_MIN


def test_kept_is_the_value_or_positive_zero_bit_for_bit() -> None:
    """``_kept(x, keep)``, the kernels' branch-free ``x if keep else +0.0``, on the awkward
    floats too (-0, infinities, NaN, subnormals): the same bits as the branch."""
    from numba import njit

    from ftgspp.render import cpu_kernels as k

    kept = njit(lambda x, keep: k._kept(x, keep))
    xs = np.array([1.5, -2.25, 0.0, -0.0, np.inf, -np.inf, np.nan, 1e-45, -3e-39, 3.4e38], np.float32)
    for x in xs:
        assert np.float32(kept(x, True)).tobytes() == x.tobytes()
        assert np.float32(kept(x, False)).tobytes() == np.float32(0.0).tobytes()


def test_pick_is_one_of_its_two_values_bit_for_bit() -> None:
    """``_pick(keep, a, b)``, the kernels' branch-free ``a if keep else b``, returns exactly one
    argument's bits on the awkward floats too (-0, infinities, NaN, subnormals)."""
    from numba import njit

    from ftgspp.render import cpu_kernels as k

    pick = njit(lambda keep, a, b: k._pick(keep, a, b))
    xs = np.array([1.5, -2.25, 0.0, -0.0, np.inf, -np.inf, np.nan, 1e-45, -3e-39, 3.4e38], np.float32)
    for a in xs:
        for b in xs[::-1]:
            assert np.float32(pick(True, a, b)).tobytes() == a.tobytes()
            assert np.float32(pick(False, a, b)).tobytes() == b.tobytes()


def test_balance_tiles_deals_every_tile_once() -> None:
    cost = np.array([5.0, 0.0, 9.0, 1.0, 9.0, 3.0, 2.0])
    for n_workers in (1, 2, 3, 8):
        offsets, tiles = cpu._k.balance_tiles(cost, n_workers)
        assert offsets[0] == 0 and offsets[-1] == len(cost)
        assert sorted(tiles.tolist()) == list(range(len(cost)))
    offsets, tiles = cpu._k.balance_tiles(cost, 2)
    loads = [cost[tiles[offsets[w] : offsets[w + 1]]].sum() for w in range(2)]
    assert abs(loads[0] - loads[1]) <= cost.max()


def test_too_many_gaussians_on_one_tile_is_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """Stop slots live in float32 tile state; a tile list that long is refused, not mis-rendered."""
    scene = make_scene(10)
    monkeypatch.setattr(cpu._k, "MAX_TILE_LIST", 8)  # any real scene has a tile with more
    with pytest.raises(ValueError, match="overlap one 16x16 tile"):
        run(cpu.rasterize, scene)


_COMPILE_OR_LOAD = """
import hashlib, json, torch
from ftgspp.bench.random_scene import project_scene, random_scene
from ftgspp.render import cpu
from ftgspp.render import cpu_kernels as k
inputs = project_scene(random_scene(300, 64, 48, seed=5))
leaves = [inputs[n].clone().requires_grad_(True) for n in ("means2d", "conics", "colors", "opacities", "depths")]
outs = cpu.rasterize(*leaves, inputs["radii"], 64, 48, inputs["background"])
g = torch.Generator().manual_seed(6)
torch.autograd.backward(outs, [torch.randn(o.shape, generator=g) for o in outs])
digest = hashlib.sha256()
for t in (*outs, *(leaf.grad for leaf in leaves)):
    digest.update(t.detach().numpy().tobytes())
standalone = {name: len(getattr(k, name).signatures) for name in ("_forward_tile", "_backward_tile")}
hits = sum(sum(getattr(k, name).stats.cache_hits.values()) for name in ("render_forward", "render_backward"))
print(json.dumps({"sha": digest.hexdigest(), "standalone": standalone, "cache_hits": hits}))
"""


@pytest.mark.slow
def test_the_process_that_compiles_the_kernels_runs_the_same_code_as_one_that_loads_them(tmp_path) -> None:
    """In a process that compiled them, the JIT linker bound the parallel kernels' calls to a
    standalone copy of the per-tile kernels (slower code; the rasterizer ran 5-6x slower
    there than in processes that loaded the cache). The tile kernels must exist only inlined
    into their parallel kernels, and both kinds of process must give the same bits."""
    import json
    import os
    import subprocess
    import sys

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))  # empty: the first process compiles
    runs = []
    for _ in range(2):  # compile, then load from the cache
        proc = subprocess.run([sys.executable, "-c", _COMPILE_OR_LOAD], env=env, capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr[-2000:]
        runs.append(json.loads(proc.stdout.strip().splitlines()[-1]))
    compiled, loaded = runs
    assert (compiled["cache_hits"], loaded["cache_hits"]) == (0, 2)  # compiled, then loaded
    assert compiled["standalone"] == {"_forward_tile": 0, "_backward_tile": 0}
    assert compiled["sha"] == loaded["sha"]


@pytest.mark.parametrize("rb", [8, 16])
def test_column_blocks_hold_every_pixel_a_gaussian_can_reach(rb: int) -> None:
    """The blocks of ``rb`` columns a Gaussian visits (``RB`` is 16 on AVX-512, 8 on AVX2) hold
    every pixel of its tile where alpha >= 1/255, computed in float64 from the conic; and they
    skip blocks (the point of them)."""
    from ftgspp.render import cpu_kernels as k

    s = make_scene(3)
    m, c, o = (s[n].detach().numpy() for n in ("means2d", "conics", "opacities"))
    b = k.bin_gaussians(m, c, o, s["radii"].numpy().astype(np.int64), s["width"], s["height"])
    tiles_x = (s["width"] + k.TS - 1) // k.TS
    visited = reached = 0
    for t in range(len(b.offsets) - 1):
        x0, y0 = (t % tiles_x) * k.TS, (t // tiles_x) * k.TS
        xs, ys = np.meshgrid(np.arange(x0, x0 + k.TS), np.arange(y0, y0 + k.TS))
        for g in b.pair_gauss[b.offsets[t]: b.offsets[t + 1]]:
            dx, dy = xs - np.float64(m[g, 0]), ys - np.float64(m[g, 1])
            a, bb, cc = np.float64(c[g])
            alpha = o[g] * np.exp(-0.5 * (a * dx * dx + cc * dy * dy) - bb * dx * dy)
            cols = np.unique(xs[(alpha >= ALPHA_MIN) & (ys < s["height"])] - x0)
            b0, b1 = k._column_blocks(b.span, g, x0, rb)
            assert np.all((cols // rb >= b0) & (cols // rb < b1)), (t, g, cols, b0, b1)
            visited += max(b1 - b0, 0)
            reached += len(np.unique(cols // rb))
    assert reached <= visited < (len(b.pair_gauss) * k.TS // rb)


@pytest.mark.parametrize("seed", [3, 4])
def test_row_ranges_hold_every_pixel_a_gaussian_can_reach(seed: int) -> None:
    """The rows a pair visits (``_row_range``: the rows its ellipse crosses within the tile's
    columns) hold every pixel of the tile where alpha >= 1/255, computed in float64 from the
    conic; and they are tighter than the ellipse's rows over the whole image width (what the
    kernels visited before), which is the point of them."""
    from ftgspp.render import cpu_kernels as k

    s = make_scene(seed)
    m, c, o = (s[n].detach().numpy() for n in ("means2d", "conics", "opacities"))
    width, height = s["width"], s["height"]
    b = k.bin_gaussians(m, c, o, s["radii"].numpy().astype(np.int64), width, height)
    tiles_x = (width + k.TS - 1) // k.TS
    visited = band_rows = reached = 0
    for t in range(len(b.offsets) - 1):
        x0, y0 = (t % tiles_x) * k.TS, (t // tiles_x) * k.TS
        x1, y1 = min(x0 + k.TS, width), min(y0 + k.TS, height)
        xs, ys = np.meshgrid(np.arange(x0, x1), np.arange(y0, y1))
        for g in b.pair_gauss[b.offsets[t]: b.offsets[t + 1]]:
            dx, dy = xs - np.float64(m[g, 0]), ys - np.float64(m[g, 1])
            a, bb, cc = np.float64(c[g])
            alpha = o[g] * np.exp(-0.5 * (a * dx * dx + cc * dy * dy) - bb * dx * dy)
            # 1e-5 below the threshold: also every pixel the kernels' float32 test could pass
            # by rounding (their exp is within one ulp, their power within ~1e-6 relative)
            rows = np.unique(ys[alpha >= ALPHA_MIN * (1 - 1e-5)])
            r0, r1 = k._row_range(b.span, g, x0, x1, y0, y1)
            assert np.all((rows >= r0) & (rows < r1)), (t, g, rows, r0, r1)
            visited += max(r1 - r0, 0)
            reached += len(rows)
            if b.span[g, k.S_FULL]:
                band_rows += y1 - y0
            else:  # the rows of the ellipse over the whole image width, as before
                my, yr = b.span[g, k.S_MY], b.span[g, k.S_YR]
                band_rows += max(0, min(y1 - 1, np.floor(my + yr)) - max(y0, np.ceil(my - yr)) + 1)
    assert reached <= visited < 0.9 * band_rows, (reached, visited, band_rows)


def test_vector_lanes_follow_the_compile_target(monkeypatch: pytest.MonkeyPatch) -> None:
    import llvmlite.binding as ll

    from ftgspp.runtime.jit import vector_lanes

    host = 16 if ll.get_host_cpu_features().get("avx512f") else 8
    for name, features, lanes in (("haswell", "", 8), ("znver3", "", 8), ("skylake-avx512", "", 16),
                                  ("znver4", "", 16), ("sapphirerapids", "-prefer-256-bit", 16),
                                  ("host", "+avx2,-avx512f", 8), ("host", "+avx512f,+avx2", 16),
                                  ("haswell", None, host), ("znver4", None, host)):  # Numba: unset = host's
        monkeypatch.setenv("NUMBA_CPU_NAME", name)
        if features is None:
            monkeypatch.delenv("NUMBA_CPU_FEATURES", raising=False)
        else:
            monkeypatch.setenv("NUMBA_CPU_FEATURES", features)
        assert vector_lanes() == lanes, (name, features)


def test_the_bench_targets_and_the_row_width_agree_on_avx512() -> None:
    """``ftgspp bench --target`` labels a CPU AVX-512 exactly when the kernels give it 16 lanes."""
    from ftgspp.bench.isa import TARGET_ISA
    from ftgspp.runtime.jit import AVX512_CPUS

    assert {n for n, isa in TARGET_ISA.items() if isa == "avx512f"} <= AVX512_CPUS
    assert not {n for n, isa in TARGET_ISA.items() if isa != "avx512f"} & AVX512_CPUS
