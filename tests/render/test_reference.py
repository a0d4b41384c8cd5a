"""Reference rasterizer against a per-pixel loop written straight from the contract, and render()."""

from __future__ import annotations

import math
import sys

import pytest
import torch

import ftgspp.render.reference as reference
from ftgspp.render import render, resolve_backend
from ftgspp.render.contract import ALPHA_MAX, ALPHA_MIN, T_MIN
from ftgspp.render.reference import rasterize

W, H = 20, 17  # 2 x 2 tiles, the last row and column of tiles partly outside the image


# ---------------------------------------------------------------------------------------
# The oracle: ftgspp/render/contract.py, one pixel at a time, in Python floats.


def brute_force(means2d, conics, colors, opacities, depths, radii, width, height, background=None):
    """Returns (image, alpha, depth) as nested lists, plus the per-pair threshold margins."""
    tiles_x, tiles_y = math.ceil(width / 16), math.ceil(height / 16)
    m, q, col = means2d.tolist(), conics.tolist(), colors.tolist()
    o, z, r = opacities.tolist(), depths.tolist(), radii.tolist()
    bg = [0.0] * len(col[0]) if background is None else background.tolist()
    rect = {}
    for k in range(len(m)):
        if min(r[k]) > 0:  # gsplat's tile range, on its pixel coordinates (ours + 0.5)
            x, y = m[k][0] + 0.5, m[k][1] + 0.5
            rx, ry = r[k]
            rect[k] = (
                min(max(math.floor(x / 16 - rx / 16), 0), tiles_x),
                min(max(math.ceil(x / 16 + rx / 16), 0), tiles_x),
                min(max(math.floor(y / 16 - ry / 16), 0), tiles_y),
                min(max(math.ceil(y / 16 + ry / 16), 0), tiles_y),
            )
    order = sorted(range(len(m)), key=lambda k: (z[k], k))
    image, alpha_img, depth_img = [], [], []
    margin = math.inf  # distance of any decision from its threshold (relative)
    for i in range(height):
        row_c, row_a, row_d = [], [], []
        for j in range(width):
            T, c, d = 1.0, [0.0] * len(bg), 0.0
            for k in order:
                if k not in rect:
                    continue
                tx0, tx1, ty0, ty1 = rect[k]
                if not (tx0 <= j // 16 < tx1 and ty0 <= i // 16 < ty1):
                    continue
                dx, dy = j - m[k][0], i - m[k][1]
                a, b, cc = q[k]
                power = -0.5 * (a * dx * dx + cc * dy * dy) - b * dx * dy
                if power > 0:
                    continue
                raw = o[k] * math.exp(power)
                alpha = min(ALPHA_MAX, raw)
                margin = min(margin, abs(raw / ALPHA_MAX - 1), abs(raw / ALPHA_MIN - 1))
                if alpha < ALPHA_MIN:
                    continue
                t_next = T * (1 - alpha)
                margin = min(margin, abs(t_next / T_MIN - 1))
                if t_next <= T_MIN:
                    break
                w = alpha * T
                c = [ci + w * col[k][ch] for ch, ci in enumerate(c)]
                d += w * z[k]
                T = t_next
            row_c.append([ci + T * b for ci, b in zip(c, bg)])
            row_a.append([1 - T])
            row_d.append([d])
        image.append(row_c)
        alpha_img.append(row_a)
        depth_img.append(row_d)
    return torch.tensor(image), torch.tensor(alpha_img), torch.tensor(depth_img), margin


# ---------------------------------------------------------------------------------------
# Scenes


def conic_and_radius(sx: float, sy: float, rho: float) -> tuple[list[float], list[int]]:
    """Conic and a 3-sigma box per axis (short of where alpha reaches 1/255: truncation is exercised)."""
    cov = torch.tensor([[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]], dtype=torch.float64)
    inv = torch.linalg.inv(cov)
    return [inv[0, 0].item(), inv[0, 1].item(), inv[1, 1].item()], [math.ceil(3 * sx), math.ceil(3 * sy)]


def mixed_scene(seed: int = 0, n_random: int = 22):
    """~30 Gaussians: random overlapping ones plus tiny, huge, off-screen, culled, tied,
    radius-truncated, non-positive-definite and an opaque stack that terminates early."""
    g = torch.Generator().manual_seed(seed)
    rows = []  # (x, y, sx, sy, rho, opacity, depth, radius override)
    for _ in range(n_random):
        x, y = (torch.rand(2, generator=g) * torch.tensor([W + 6.0, H + 6.0]) - 3).tolist()
        sx, sy = (torch.rand(2, generator=g) * 3 + 0.4).tolist()
        rho = (torch.rand(1, generator=g).item() - 0.5) * 1.4
        o = 0.05 + 0.9 * torch.rand(1, generator=g).item()
        rows.append((x, y, sx, sy, rho, o, 1 + 9 * torch.rand(1, generator=g).item(), None))
    rows += [
        (7.3, 5.6, 0.2, 0.25, 0.1, 0.9, 2.0, None),  # tiny
        (9.0, 8.0, 40.0, 30.0, 0.3, 0.3, 7.0, None),  # huge, covers all tiles
        (-6.0, 8.0, 4.0, 4.0, 0.0, 0.8, 3.0, None),  # centre off-screen, reaches in
        (10.0, 8.0, 3.0, 3.0, 0.0, 0.9, 0.5, 0),  # culled (radius 0) in front of everything
        (12.0, 4.0, 2.0, 2.0, 0.2, 0.6, 4.0, None),  # two at the same depth: ties by index
        (12.5, 4.5, 2.5, 1.5, -0.2, 0.6, 4.0, None),
        (14.0, 12.0, 3.0, 3.0, 0.0, 0.9, 1.5, 1),  # radius 1: tile 0 only, visible in tile 1 if not masked
        # Opaque stack: stops at the 3rd layer near its centre.
        (18.0, 15.0, 6.0, 6.0, 0.0, 0.97, 0.1, None),
        (18.0, 15.0, 6.0, 6.0, 0.0, 0.98, 0.2, None),
        (18.0, 15.0, 6.0, 6.0, 0.0, 1.0, 0.3, None),
    ]
    n = len(rows)
    means2d = torch.tensor([[r[0], r[1]] for r in rows], dtype=torch.float64)
    conics, radii = [], []
    for x, y, sx, sy, rho, o, z, r_override in rows:
        con, rad = conic_and_radius(sx, sy, rho)
        conics.append(con)
        radii.append(rad if r_override is None else [r_override] * 2)
    conics = torch.tensor(conics, dtype=torch.float64)
    conics[3] = torch.tensor([0.1, 0.5, 0.1])  # not positive definite: power > 0 along a diagonal
    radii[3] = [12, 9]
    colors = torch.rand(n, 3, generator=g, dtype=torch.float64)
    opacities = torch.tensor([r[5] for r in rows], dtype=torch.float64)
    depths = torch.tensor([r[6] for r in rows], dtype=torch.float64)
    return means2d, conics, colors, opacities, depths, torch.tensor(radii, dtype=torch.int32)


# ---------------------------------------------------------------------------------------
# Forward against the oracle


@pytest.mark.parametrize("seed", [0, 1])
def test_matches_brute_force(seed: int) -> None:
    scene = mixed_scene(seed)
    bg = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    got = rasterize(*scene, W, H, bg)
    want = brute_force(*scene, W, H, bg)
    for g, w in zip(got, want[:3]):
        assert g.shape == w.shape
        torch.testing.assert_close(g, w.to(g.dtype), atol=1e-6, rtol=0)


def test_chunking_does_not_change_the_result(monkeypatch) -> None:
    scene = mixed_scene(2)
    full = rasterize(*scene, W, H)
    monkeypatch.setattr(reference, "CHUNK_ELEMENTS", 1)  # one tile per chunk
    for a, b in zip(full, rasterize(*scene, W, H)):
        torch.testing.assert_close(a, b, atol=1e-12, rtol=0)


def test_radius_limits_a_gaussian_to_its_tiles() -> None:
    means2d = torch.tensor([[14.0, 8.0]], dtype=torch.float64)  # px 15 in tile 0, px 16 in tile 1
    conics = torch.tensor([[0.25, 0.0, 0.25]], dtype=torch.float64)  # sigma 2 px
    args = (conics, torch.ones(1, 1, dtype=torch.float64), torch.tensor([0.9], dtype=torch.float64),
            torch.ones(1, dtype=torch.float64))  # fmt: skip
    # x' = 14.5: tiles floor(14.5/16 - 1/16) = 0 to ceil(14.5/16 + 1/16) = 1, exclusive
    _, alpha, _ = rasterize(means2d, *args, torch.tensor([[1, 1]], dtype=torch.int32), W, H)
    assert alpha[8, 14, 0] > 0.8 and alpha[8, 15, 0] > 0.5 and alpha[8, 16, 0] == 0
    _, alpha, _ = rasterize(means2d, *args, torch.tensor([[2, 1]], dtype=torch.int32), W, H)  # ceil(15.5/16 + ...) = 2
    torch.testing.assert_close(alpha[8, 16, 0], alpha[8, 12, 0])
    _, alpha, _ = rasterize(means2d, *args, torch.tensor([[6, 0]], dtype=torch.int32), W, H)
    assert (alpha == 0).all()  # a radius of 0 on either axis culls


def test_float32_agrees_with_float64() -> None:
    scene = mixed_scene(3)
    f64 = rasterize(*scene, W, H)
    f32 = rasterize(*[t.float() if t.is_floating_point() else t for t in scene], W, H)
    for a, b in zip(f64, f32):
        torch.testing.assert_close(b.double(), a, atol=1e-4, rtol=0)


def test_empty_input_renders_background() -> None:
    bg = torch.tensor([0.1, 0.2], dtype=torch.float64)
    z = torch.zeros(0, dtype=torch.float64)
    image, alpha, depth = rasterize(torch.zeros(0, 2).double(), torch.zeros(0, 3).double(), torch.zeros(0, 2).double(),
                                    z, z, torch.zeros(0, 2, dtype=torch.int32), W, H, bg)  # fmt: skip
    torch.testing.assert_close(image, bg.expand(H, W, 2))
    assert (alpha == 0).all() and (depth == 0).all()


# ---------------------------------------------------------------------------------------
# Early termination


def flat_stack(opacities: list[float], conic: float = 1e-8):
    """Wide, nearly flat Gaussians stacked in depth over the whole image."""
    n = len(opacities)
    means2d = torch.tensor([[10.0, 8.0]] * n, dtype=torch.float64)
    conics = torch.tensor([[conic, 0.0, conic]] * n, dtype=torch.float64)
    colors = torch.eye(n, dtype=torch.float64)  # Gaussian k paints channel k
    depths = torch.arange(1, n + 1, dtype=torch.float64)
    radii = torch.full((n, 2), 30_000, dtype=torch.int32)
    return means2d, conics, colors, torch.tensor(opacities, dtype=torch.float64), depths, radii


def test_opaque_stack_stops_and_weights_the_background() -> None:
    scene = flat_stack([0.95] * 5)
    bg = torch.full((5,), 2.0, dtype=torch.float64)
    image, alpha, depth = rasterize(*scene, W, H, bg)
    # T: 1, 0.05, 2.5e-3, 1.25e-4, then 6.25e-6 < 1e-4: the 4th and 5th are never added.
    dx2 = ((torch.arange(W, dtype=torch.float64) - 10.0) ** 2)[None, :]
    dy2 = ((torch.arange(H, dtype=torch.float64) - 8.0) ** 2)[:, None]
    a = 0.95 * torch.exp(-0.5 * 1e-8 * (dx2 + dy2))  # [H, W]
    w = [a, a * (1 - a), a * (1 - a) ** 2]
    t_final = (1 - a) ** 3
    for k in range(3):
        torch.testing.assert_close(image[..., k], w[k] + 2.0 * t_final)
    torch.testing.assert_close(image[..., 3], 2.0 * t_final)
    torch.testing.assert_close(image[..., 4], 2.0 * t_final)
    torch.testing.assert_close(alpha[..., 0], 1 - t_final)
    torch.testing.assert_close(depth[..., 0], w[0] * 1 + w[1] * 2 + w[2] * 3)


def test_nothing_behind_the_stop_gets_gradient() -> None:
    means2d, conics, colors, opacities, depths, radii = flat_stack([0.95] * 5)
    colors.requires_grad_()
    opacities.requires_grad_()
    image, _, _ = rasterize(means2d, conics, colors, opacities, depths, radii, W, H)
    image.sum().backward()
    assert (colors.grad[3:] == 0).all() and (opacities.grad[3:] == 0).all()
    assert (colors.grad[:3].diagonal() > 0).all() and (opacities.grad[:3] != 0).all()


# ---------------------------------------------------------------------------------------
# Gradients against finite differences


def small_scene(seed: int):
    g = torch.Generator().manual_seed(seed)
    n = 6
    means2d = (torch.rand(n, 2, generator=g, dtype=torch.float64) * torch.tensor([W, H]) * 0.8 + 2).double()
    conics = []
    for _ in range(n):
        sx, sy = (torch.rand(2, generator=g) * 2 + 1.5).tolist()
        conics.append(conic_and_radius(sx, sy, (torch.rand(1, generator=g).item() - 0.5))[0])
    conics = torch.tensor(conics, dtype=torch.float64)
    colors = torch.rand(n, 3, generator=g, dtype=torch.float64)
    opacities = torch.rand(n, generator=g, dtype=torch.float64) * 0.6 + 0.3
    opacities[0] = 1.0  # the 0.999 clamp may be active near its centre
    depths = torch.rand(n, generator=g, dtype=torch.float64) * 5 + 1
    radii = torch.full((n, 2), 12, dtype=torch.int32)  # several tiles each: tile masking is exercised
    return means2d, conics, colors, opacities, depths, radii


@pytest.mark.parametrize(
    "scene",
    # early_stop: T after three layers ~1e-3, the 4th would take it to ~5e-5 in every pixel.
    [small_scene(0), small_scene(1), flat_stack([0.9, 0.9, 0.9, 0.95, 0.9], conic=2e-5)],
    ids=["random0", "random1", "early_stop"],
)
def test_gradcheck(scene) -> None:
    means2d, conics, colors, opacities, depths, radii = scene
    margin = brute_force(*scene, W, H)[3]
    assert margin > 1e-4, "scene too close to a threshold for finite differences"
    bg = torch.tensor([0.3] * colors.shape[1], dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    proj = [torch.randn(H, W, c, generator=g, dtype=torch.float64) for c in (colors.shape[1], 1, 1)]

    def f(m, q, c, o, z):  # random projection of all three outputs: one backward per check
        outs = rasterize(m, q, c, o, z, radii, W, H, bg)
        return sum((p * out).sum() for p, out in zip(proj, outs))

    inputs = tuple(t.clone().requires_grad_() for t in (means2d, conics, colors, opacities, depths))
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


# ---------------------------------------------------------------------------------------
# render(): projection + rasterization end to end


def camera(width: int, height: int, f: float = 40.0):
    K = torch.tensor([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]], dtype=torch.float64)
    return torch.eye(4, dtype=torch.float64), K


def test_render_single_isotropic_gaussian() -> None:
    width, height, f, z, s, o = 33, 25, 40.0, 4.0, 0.1, 0.8
    viewmat, K = camera(width, height, f)
    means = torch.tensor([[0.0, 0.0, z]], dtype=torch.float64, requires_grad=True)
    quats = torch.tensor([[0.9, 0.1, -0.3, 0.2]], dtype=torch.float64)  # irrelevant: isotropic
    scales = torch.full((1, 3), s, dtype=torch.float64)
    color, bg = torch.tensor([[1.0, 0.5, 0.0]], dtype=torch.float64), torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    out = render(means, quats, scales, torch.tensor([o], dtype=torch.float64), color, viewmat, K, width, height, bg)
    var = (f * s / z) ** 2 + 0.3  # on the optical axis J = diag(f / z)
    extend = math.sqrt(2 * math.log(o * 255))  # where alpha falls to 1/255, in sigmas
    assert out.radii[0].tolist() == [math.ceil(extend * math.sqrt(var))] * 2
    cols = torch.arange(width, dtype=torch.float64) - 16
    expected_alpha = o * torch.exp(-0.5 * cols**2 / var)
    expected_alpha = torch.where(expected_alpha >= ALPHA_MIN, expected_alpha, 0.0)
    row = out.alpha[12, :, 0]
    torch.testing.assert_close(row, expected_alpha)  # radius 4: both tile columns are touched
    torch.testing.assert_close(out.image[12, 16], torch.tensor([o, 0.5 * o, 1 - o], dtype=torch.float64))
    torch.testing.assert_close(out.depth[12, 16, 0], torch.tensor(o * z, dtype=torch.float64))
    # The screen-space gradient is kept for the relocation score.
    out.image[12, 18, 0].backward()
    assert out.means2d.grad is not None and out.means2d.grad[0, 0] > 0  # moving right brightens px 18
    assert means.grad[0, 0] > 0


def test_render_behind_camera_is_invisible_with_zero_gradient() -> None:
    viewmat, K = camera(W, H)
    bg = torch.tensor([0.4, 0.4, 0.4], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 3, dtype=torch.float64)
    visible = torch.tensor([[0.0, 0.0, 3.0]], dtype=torch.float64)
    hidden = torch.tensor([[0.0, 0.0, -3.0], [0.0, 0.0, 0.005]], dtype=torch.float64)  # behind, before near
    scales = torch.full((3, 3), 0.5, dtype=torch.float64, requires_grad=True)
    ones = torch.ones(3, 3, dtype=torch.float64)
    alone = render(visible, quats[:1], scales[:1], ones[0, :1], ones[:1], viewmat, K, W, H, bg)
    means = torch.cat([hidden, visible]).requires_grad_()
    out = render(means, quats, scales, torch.ones(3, dtype=torch.float64), torch.ones(3, 3, dtype=torch.float64),
                 viewmat, K, W, H, bg)  # fmt: skip
    assert out.radii.tolist()[:2] == [[0, 0], [0, 0]] and (out.radii[2] > 0).all()
    torch.testing.assert_close(out.image, alone.image)
    out.image.sum().backward()
    assert (means.grad[:2] == 0).all() and (scales.grad[:2] == 0).all()
    assert torch.isfinite(means.grad).all() and means.grad[2].abs().sum() > 0


def test_render_depth_of_an_opaque_flat_layer() -> None:
    viewmat, K = camera(W, H)
    z = 2.5
    xs, ys = torch.meshgrid(torch.linspace(-0.9, 0.9, 10), torch.linspace(-0.7, 0.7, 8), indexing="ij")
    means = torch.stack([xs.flatten(), ys.flatten(), torch.full((80,), z)], -1).double()
    quats = torch.tensor([[1.0, 0, 0, 0]] * 80, dtype=torch.float64)
    scales = torch.tensor([[0.15, 0.15, 0.01]] * 80, dtype=torch.float64)
    out = render(means, quats, scales, torch.full((80,), 0.9, dtype=torch.float64),
                 torch.rand(80, 3, dtype=torch.float64), viewmat, K, W, H)  # fmt: skip
    assert out.alpha.min() > 0.95
    torch.testing.assert_close(out.depth, z * out.alpha)  # normalised depth == z everywhere


def test_render_backend_dispatch(monkeypatch) -> None:
    viewmat, K = camera(W, H)
    args = (torch.zeros(1, 3), torch.tensor([[1.0, 0, 0, 0]]), torch.ones(1, 3), torch.ones(1), torch.ones(1, 3),
            viewmat.float(), K.float(), W, H)  # fmt: skip
    with pytest.raises(ValueError, match="unknown render backend"):
        render(*args, backend="nope")
    with pytest.raises(RuntimeError, match="gsplat"):
        render(*args, backend="gsplat")  # CPU tensors
    assert resolve_backend("auto", torch.device("cpu")) in ("cpu", "reference")
    monkeypatch.setitem(sys.modules, "ftgspp.render.cpu", None)  # as if the module were missing
    with pytest.raises(RuntimeError, match="'cpu' is unavailable"):
        render(*args, backend="cpu")
    assert resolve_backend("auto", torch.device("cpu")) == "reference"
    assert render(*args, backend="auto").image.shape == (H, W, 3)


def test_tile_ranges_builds_its_constants_on_the_inputs_device():
    """The GPU check's parity failed on CUDA ("cuda:0 and cpu") because the tile limits were a CPU
    tensor; the meta device shows the same mismatch without a GPU."""
    from ftgspp.render.reference import tile_ranges

    means2d = torch.zeros(5, 2, device="meta")
    radii = torch.ones(5, 2, dtype=torch.int32, device="meta")
    assert all(t.device.type == "meta" for t in tile_ranges(means2d, radii, 64, 48))
