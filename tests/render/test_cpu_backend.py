"""The ``cpu`` rasterization backend against independent oracles.

Oracles: the reference rasterizer (pure PyTorch autograd, tile-masked like the contract) for
images and every gradient, a float64 per-pixel Python loop written from the contract in
ftgspp/render/contract.py for the forward pass, and the bench's dense yardstick (every
Gaussian-pixel pair). Scenes (``cpu_scenes.py``) mix overlapping, tiny, huge, needle-like,
indefinite, behind-camera (radius 0), off-screen, saturated and radius-truncated Gaussians
on an image whose size is not a multiple of the tile size. The kernels' own pieces are
tested in ``test_cpu_kernels.py``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ftgspp.render import cpu
from ftgspp.render.contract import ALPHA_MAX, ALPHA_MIN, T_MIN, TILE_SIZE
from ftgspp.render.reference import rasterize as reference_rasterize
from tests.numba_threads import under_thread_counts
from tests.render.cpu_scenes import GRAD_INPUTS, HEIGHT, WIDTH, assert_grad_close, make_scene, run


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
    culled = (scene["radii"] == 0).any(-1)
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
                x, y, (rx, ry) = means[k, 0], means[k, 1], radii[k]
                if min(rx, ry) <= 0:
                    continue
                gx, gy = x + 0.5, y + 0.5  # gsplat's pixel coordinates
                tx0 = min(max(math.floor(gx / 16 - rx / 16), 0), tiles_x)
                tx1 = min(max(math.ceil(gx / 16 + rx / 16), 0), tiles_x)
                ty0 = min(max(math.floor(gy / 16 - ry / 16), 0), tiles_y)
                ty1 = min(max(math.ceil(gy / 16 + ry / 16), 0), tiles_y)
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
                if t_next <= T_MIN:
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
    keep = torch.arange(scene["radii"].shape[0]) % 3 == 0  # a lighter scene keeps the loop quick
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
    """One Gaussian, o = 1: alpha is clamped at 0.999 where exp(power) > 0.999, as in autograd."""
    means2d = torch.tensor([[8.0, 8.0]], requires_grad=True)
    conics = torch.tensor([[1.0, 0.0, 1.0]], requires_grad=True)
    opac = torch.tensor([1.0], requires_grad=True)
    colors, depths = torch.ones(1, 1), torch.ones(1)
    image, _, _ = cpu.rasterize(means2d, conics, colors, opac, depths, torch.tensor([[3, 3]]), 17, 17)
    weight = torch.zeros(17, 17, 1)
    weight[8, 8] = 1.0  # only the centre pixel, where alpha is clamped
    (image * weight).sum().backward()
    assert image[8, 8, 0].item() == pytest.approx(0.999)
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
