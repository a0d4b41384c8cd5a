"""The ``cpu`` rasterization backend against independent oracles.

Oracles: the reference rasterizer (pure PyTorch autograd, tile-masked like the contract) for
images and every gradient, and a float64 per-pixel Python loop written from the contract in
docs/CONTRACTS.md for the forward pass. Scenes mix overlapping, tiny, huge, needle-like,
indefinite, behind-camera (radius 0), off-screen, saturated and radius-truncated Gaussians
on an image whose size is not a multiple of the tile size.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ftgspp.render.contract import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE_SIZE
from ftgspp.render import cpu
from ftgspp.render.reference import rasterize as reference_rasterize
from tests.numba_threads import under_thread_counts

WIDTH, HEIGHT = 53, 41  # 4 x 3 tiles, the last row and column partial


def _conics_and_radii(sigma: torch.Tensor, angle: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Conic (a, b, c) of a rotated 2D Gaussian (+0.3 low-pass) and its 3-sigma radius."""
    c, s = torch.cos(angle), torch.sin(angle)
    rot = torch.stack([c, -s, s, c], -1).reshape(-1, 2, 2).double()
    cov = rot @ torch.diag_embed(sigma.double() ** 2) @ rot.transpose(1, 2) + 0.3 * torch.eye(2, dtype=torch.float64)
    inv = torch.linalg.inv(cov)
    conics = torch.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], -1).float()
    radii = torch.ceil(3 * torch.linalg.eigvalsh(cov)[:, 1].sqrt()).int()
    return conics, radii


def make_scene(seed: int, n_dim: int = 3, width: int = WIDTH, height: int = HEIGHT) -> dict:
    """A random scene with every awkward kind of Gaussian the rasterizer must handle."""
    g = torch.Generator().manual_seed(seed)

    def rand(*shape):
        return torch.rand(*shape, generator=g)

    parts = []

    def add(n, means, sigma, opac, depth=None):
        conics, radii = _conics_and_radii(sigma, rand(n) * math.pi)
        parts.append(dict(
            means2d=means, conics=conics, opacities=opac,
            depths=depth if depth is not None else 1 + 9 * rand(n), radii=radii,
        ))  # fmt: skip

    size = torch.tensor([width, height], dtype=torch.float32)
    n = 120  # ordinary: spread over and a bit beyond the image
    add(n, rand(n, 2) * size * 1.2 - 0.1 * size, 0.5 + 3 * rand(n, 2), rand(n))
    n = 40  # overlapping cluster
    add(n, 20 + 3 * rand(n, 2), 2 + 2 * rand(n, 2), 0.3 + 0.7 * rand(n))
    n = 30  # opaque stack: transmittance falls below T_MIN and pixels stop early
    add(n, torch.tensor([35.0, 12.0]) + rand(n, 2), 3 + rand(n, 2), torch.full((n,), 0.995))
    n = 20  # saturated opacities (0.99 clamp active near the centres)
    add(n, rand(n, 2) * size, 1 + 2 * rand(n, 2), 1 - 0.005 * rand(n))
    n = 30  # tiny
    add(n, rand(n, 2) * size, 0.05 + 0.3 * rand(n, 2), rand(n))
    n = 4  # huge, covering many tiles
    add(n, rand(n, 2) * size, 25 + 30 * rand(n, 2), 0.2 * rand(n))
    n = 4  # needles (ill-conditioned conics)
    add(n, rand(n, 2) * size, torch.stack([150 + 100 * rand(n), 0.1 * rand(n)], -1), 0.5 + 0.5 * rand(n))
    n = 10  # off-screen: some reach into the image with their radius, some do not
    off = torch.stack([-8 - 10 * rand(n), height + 2 + 10 * rand(n)], -1)
    add(n, off, 3 + 3 * rand(n, 2), 0.5 + 0.5 * rand(n))
    n = 10  # equal depths: ties broken by index
    add(n, 10 + 20 * rand(n, 2), 2 + 2 * rand(n, 2), 0.5 + 0.5 * rand(n), torch.full((n,), 4.0))
    n = 10  # behind the camera: radius 0, negative depth, arbitrary 2D values
    add(n, rand(n, 2) * size, 1 + 3 * rand(n, 2), rand(n), -1 - rand(n))
    parts[-1]["radii"][:] = 0
    n = 8  # radius smaller than the footprint: cut at tile boundaries
    add(n, rand(n, 2) * size, 5 + 5 * rand(n, 2), 0.5 + 0.5 * rand(n))
    parts[-1]["radii"] = (parts[-1]["radii"] // 4).clamp_min(1)
    n = 3  # indefinite conics (b^2 > ac): power can be positive, skipped per pixel
    add(n, rand(n, 2) * size, 2 + rand(n, 2), 0.5 + 0.5 * rand(n))
    parts[-1]["conics"][:, 1] = 2 * torch.sqrt(parts[-1]["conics"][:, 0] * parts[-1]["conics"][:, 2])

    scene = {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
    total = scene["means2d"].shape[0]
    perm = torch.randperm(total, generator=g)
    scene = {k: v[perm].contiguous() for k, v in scene.items()}
    scene["colors"] = rand(total, n_dim)
    scene["background"] = rand(n_dim)
    scene["width"], scene["height"] = width, height
    return scene


GRAD_INPUTS = ("means2d", "conics", "colors", "opacities", "depths", "background")


def run(rasterize, scene: dict, seed: int = 0) -> tuple[tuple[torch.Tensor, ...], dict[str, torch.Tensor]]:
    """Forward, then backward of <outputs, fixed random cotangents>. Returns (outputs, grads)."""
    inputs = {k: scene[k].clone().requires_grad_(True) for k in GRAD_INPUTS}
    outputs = rasterize(
        inputs["means2d"], inputs["conics"], inputs["colors"], inputs["opacities"], inputs["depths"],
        scene["radii"], scene["width"], scene["height"], inputs["background"],
    )  # fmt: skip
    g = torch.Generator().manual_seed(1000 + seed)
    cotangents = [torch.randn(o.shape, generator=g) for o in outputs]
    torch.autograd.backward(outputs, cotangents)
    return tuple(o.detach() for o in outputs), {k: v.grad for k, v in inputs.items()}


def assert_grad_close(actual: torch.Tensor, expected: torch.Tensor, name: str, rel: float = 1e-4) -> None:
    """Every entry within rel * (|expected| + max |expected|) of the oracle."""
    scale = expected.abs().max().item()
    err = (actual - expected).abs()
    bound = rel * (expected.abs() + scale) + 1e-12
    worst = (err / bound).max().item()
    assert worst <= 1.0, f"{name}: max error {err.max().item():.3g} (scale {scale:.3g})"


@pytest.mark.parametrize("n_dim", [1, 3])
@pytest.mark.parametrize("seed", [0, 1])
def test_matches_reference_forward_and_gradients(n_dim: int, seed: int) -> None:
    scene = make_scene(seed, n_dim)
    (image, alpha, depth), grads = run(cpu.rasterize, scene, seed)
    (ref_image, ref_alpha, ref_depth), ref_grads = run(reference_rasterize, scene, seed)
    assert image.shape == (HEIGHT, WIDTH, n_dim) and alpha.shape == depth.shape == (HEIGHT, WIDTH, 1)
    assert (alpha > 0.5).any() and (alpha < 0.5).any()  # the scene is neither empty nor saturated
    torch.testing.assert_close(image, ref_image, rtol=0, atol=1e-5)
    torch.testing.assert_close(alpha, ref_alpha, rtol=0, atol=1e-5)
    torch.testing.assert_close(depth, ref_depth, rtol=1e-5, atol=1e-5 * ref_depth.abs().max().item())
    for name in GRAD_INPUTS:
        assert_grad_close(grads[name], ref_grads[name], name)
    culled = scene["radii"] == 0
    assert culled.any() and (grads["means2d"][culled] == 0).all() and (grads["opacities"][culled] == 0).all()


def _contract_loop(scene: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The contract's per-pixel loop in float64 (forward only): image, alpha, depth."""
    means = scene["means2d"].double().numpy()
    conics = scene["conics"].double().numpy()
    colors = scene["colors"].double().numpy()
    opac = scene["opacities"].double().numpy()
    depths = scene["depths"].double().numpy()
    radii = scene["radii"].numpy()
    bg = scene["background"].double().numpy()
    width, height = scene["width"], scene["height"]
    tiles_x, tiles_y = -(-width // TILE_SIZE), -(-height // TILE_SIZE)
    order = sorted(range(len(radii)), key=lambda k: (depths[k], k))
    image = np.zeros((height, width, colors.shape[1]))
    alpha = np.zeros((height, width, 1))
    depth = np.zeros((height, width, 1))
    for i in range(height):
        for j in range(width):
            tx, ty = j // TILE_SIZE, i // TILE_SIZE
            trans, color, z = 1.0, np.zeros(colors.shape[1]), 0.0
            for k in order:
                x, y, r = means[k, 0], means[k, 1], radii[k]
                if r <= 0:
                    continue
                tx0 = min(max(math.floor((x - r) / 16), 0), tiles_x)
                tx1 = min(max(math.floor((x + r + 15) / 16), 0), tiles_x)
                ty0 = min(max(math.floor((y - r) / 16), 0), tiles_y)
                ty1 = min(max(math.floor((y + r + 15) / 16), 0), tiles_y)
                if not (tx0 <= tx < tx1 and ty0 <= ty < ty1):
                    continue
                dx, dy = j - x, i - y
                a, b, c = conics[k]
                power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
                if power > 0:
                    continue
                al = min(ALPHA_MAX, opac[k] * math.exp(power))
                if al < ALPHA_MIN:
                    continue
                t_next = trans * (1 - al)
                if t_next < T_MIN:
                    break
                color += al * trans * colors[k]
                z += al * trans * depths[k]
                trans = t_next
            image[i, j] = color + trans * bg
            alpha[i, j] = 1 - trans
            depth[i, j] = z
    return image, alpha, depth


def test_matches_float64_contract_loop() -> None:
    scene = make_scene(3, 3, width=37, height=21)
    keep = torch.arange(scene["radii"].numel()) % 3 == 0  # a lighter scene keeps the loop quick
    for key in ("means2d", "conics", "colors", "opacities", "depths", "radii"):
        scene[key] = scene[key][keep]
    with torch.no_grad():
        outputs = cpu.rasterize(
            scene["means2d"], scene["conics"], scene["colors"], scene["opacities"], scene["depths"],
            scene["radii"], scene["width"], scene["height"], scene["background"],
        )  # fmt: skip
    for got, want in zip(outputs, _contract_loop(scene)):
        np.testing.assert_allclose(got.numpy(), want, rtol=1e-5, atol=1e-5)


def test_bitwise_deterministic_across_runs_and_thread_counts() -> None:
    scene = make_scene(4)
    results = under_thread_counts(lambda: run(cpu.rasterize, scene))
    (out0, grads0) = results[0]
    for out, grads in results[1:]:
        assert all(torch.equal(a, b) for a, b in zip(out0, out))
        assert all(torch.equal(grads0[k], grads[k]) for k in GRAD_INPUTS)


def test_empty_scene_gives_background() -> None:
    scene = make_scene(5)
    scene["radii"] = torch.zeros_like(scene["radii"])
    (image, alpha, depth), grads = run(cpu.rasterize, scene)
    torch.testing.assert_close(image, scene["background"].expand(HEIGHT, WIDTH, -1), rtol=0, atol=0)
    assert (alpha == 0).all() and (depth == 0).all()
    for name in ("means2d", "conics", "colors", "opacities", "depths"):
        assert (grads[name] == 0).all()
    # d image / d background = 1 at every pixel: the cotangent summed over pixels
    cotangent = torch.randn((HEIGHT, WIDTH, 3), generator=torch.Generator().manual_seed(1000))
    torch.testing.assert_close(grads["background"], cotangent.sum((0, 1)), rtol=1e-5, atol=1e-5)


def test_clamped_opacity_gets_no_gradient_through_the_clamp() -> None:
    """One Gaussian, o = 1: alpha is clamped at 0.99 where exp(power) > 0.99, as in autograd."""
    means2d = torch.tensor([[8.0, 8.0]], requires_grad=True)
    conics = torch.tensor([[1.0, 0.0, 1.0]], requires_grad=True)
    opac = torch.tensor([1.0], requires_grad=True)
    colors, depths = torch.ones(1, 1), torch.ones(1)
    image, _, _ = cpu.rasterize(means2d, conics, colors, opac, depths, torch.tensor([3]), 17, 17)
    weight = torch.zeros(17, 17, 1)
    weight[8, 8] = 1.0  # only the centre pixel, where alpha is clamped
    (image * weight).sum().backward()
    assert image[8, 8, 0].item() == pytest.approx(0.99)
    assert opac.grad.item() == 0.0 and (means2d.grad == 0).all() and (conics.grad == 0).all()


def test_render_end_to_end_matches_reference() -> None:
    """Gradients reach 3D parameters through the shared projection identically."""
    from ftgspp.render import render

    g = torch.Generator().manual_seed(7)
    n = 200
    params = dict(
        means=torch.cat([torch.rand(n, 2, generator=g) * 2 - 1, 2 + 3 * torch.rand(n, 1, generator=g)], -1),
        quats=torch.randn(n, 4, generator=g),
        scales=0.02 + 0.1 * torch.rand(n, 3, generator=g),
        opacities=torch.rand(n, generator=g),
        colors=torch.rand(n, 3, generator=g),
    )
    viewmat = torch.eye(4)
    K = torch.tensor([[40.0, 0, 23.5], [0, 40.0, 17.5], [0, 0, 1]])
    grads = {}
    for backend in ("cpu", "reference"):
        leaves = {k: v.clone().requires_grad_(True) for k, v in params.items()}
        out = render(leaves["means"], leaves["quats"], leaves["scales"], leaves["opacities"], leaves["colors"],
                     viewmat, K, 48, 36, backend=backend)  # fmt: skip
        loss = (out.image * torch.linspace(0, 1, 48).view(1, -1, 1)).sum() + out.depth.mean() + out.alpha.sum()
        loss.backward()
        grads[backend] = {k: v.grad for k, v in leaves.items()} | {"means2d": out.means2d.grad}
    for name in grads["reference"]:
        assert_grad_close(grads["cpu"][name], grads["reference"][name], name)


def test_float64_inputs_and_shape_errors() -> None:
    scene = make_scene(6, 1)
    with torch.no_grad():
        args = [scene[k].double() for k in ("means2d", "conics", "colors", "opacities", "depths")]
        image, alpha, depth = cpu.rasterize(*args, scene["radii"], WIDTH, HEIGHT, None)
        ref = reference_rasterize(*[a.float() for a in args], scene["radii"], WIDTH, HEIGHT, None)
    assert image.dtype == torch.float64
    torch.testing.assert_close(image.float(), ref[0], rtol=0, atol=1e-5)
    with pytest.raises(ValueError, match="conics"):
        cpu.rasterize(args[0], args[1][:, :2], *args[2:], scene["radii"], WIDTH, HEIGHT)


def test_depth_sort_keys_order_floats() -> None:
    depths = np.array([3.0, -2.0, 0.0, -0.0, 1e-30, -1e30, 7.5, 3.0], np.float32)
    keys = cpu.depth_sort_keys(depths)
    order = np.lexsort((np.arange(len(depths)), keys))
    assert list(order) == list(np.lexsort((np.arange(len(depths)), depths + 0.0)))


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


def test_balance_tiles_deals_every_tile_once() -> None:
    cost = np.array([5.0, 0.0, 9.0, 1.0, 9.0, 3.0, 2.0])
    for n_workers in (1, 2, 3, 8):
        offsets, tiles = cpu._k.balance_tiles(cost, n_workers)
        assert offsets[0] == 0 and offsets[-1] == len(cost)
        assert sorted(tiles.tolist()) == list(range(len(cost)))
    offsets, tiles = cpu._k.balance_tiles(cost, 2)
    loads = [cost[tiles[offsets[w] : offsets[w + 1]]].sum() for w in range(2)]
    assert abs(loads[0] - loads[1]) <= cost.max()


def test_matches_dense_yardstick_of_the_bench() -> None:
    """A third oracle: every Gaussian-pixel pair composited densely (``ftgspp.bench.yardstick``)."""
    from ftgspp.bench.yardstick import dense_rasterize

    scene = make_scene(9)
    (image, alpha, depth), grads = run(cpu.rasterize, scene)
    inputs = {k: scene[k].clone().requires_grad_(True) for k in GRAD_INPUTS}
    g = torch.Generator().manual_seed(1000)
    cotangents = tuple(torch.randn(s, generator=g) for s in [image.shape, alpha.shape, depth.shape])
    dense = dense_rasterize(
        *[inputs[k] for k in GRAD_INPUTS[:5]], scene["radii"], WIDTH, HEIGHT, inputs["background"],
        grads=cotangents, chunk_pairs=1 << 18,
    )  # fmt: skip
    for got, want in zip((image, alpha), dense[:2]):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-5)
    torch.testing.assert_close(depth, dense[2], rtol=1e-5, atol=1e-5 * dense[2].abs().max().item())
    for name in GRAD_INPUTS:
        assert_grad_close(grads[name], inputs[name].grad, name)


def test_editing_an_input_before_backward_raises() -> None:
    """Inputs are saved, not copied: an in-place edit before backward is an error, never stale gradients."""
    scene = make_scene(10)
    leaf = scene["means2d"].clone().requires_grad_(True)
    means2d = leaf * 1.0
    image, _, _ = cpu.rasterize(means2d, scene["conics"], scene["colors"], scene["opacities"], scene["depths"],
                                scene["radii"], WIDTH, HEIGHT)  # fmt: skip
    with torch.no_grad():
        means2d.add_(1.0)
    with pytest.raises(RuntimeError, match="inplace"):
        image.sum().backward()


def test_too_many_gaussians_on_one_tile_is_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """Stop slots live in float32 tile state; a tile list that long is refused, not mis-rendered."""
    scene = make_scene(10)
    monkeypatch.setattr(cpu._k, "MAX_TILE_LIST", 8)  # any real scene has a tile with more
    with pytest.raises(ValueError, match="overlap one 16x16 tile"):
        run(cpu.rasterize, scene)


_COMPILE_OR_LOAD = """
import hashlib, json, torch
from ftgspp.bench.scene import project_scene, random_scene
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
