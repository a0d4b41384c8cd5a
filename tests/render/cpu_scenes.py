"""Awkward random 2D scenes for the ``cpu`` rasterizer tests, and how they are run and compared.

``make_scene`` mixes overlapping, tiny, huge, needle-like, indefinite, behind-camera
(radius 0), off-screen, saturated and radius-truncated Gaussians on an image whose size is
not a multiple of the tile size; ``run`` does a forward and a backward for fixed random
cotangents; ``assert_grad_close`` compares a gradient with an oracle's.
"""

from __future__ import annotations

import math

import torch

WIDTH, HEIGHT = 53, 41  # 4 x 3 tiles, the last row and column partial


def _conics_and_radii(sigma: torch.Tensor, angle: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Conic (a, b, c) of a rotated 2D Gaussian (+0.3 low-pass) and its 3-sigma radius per axis."""
    c, s = torch.cos(angle), torch.sin(angle)
    rot = torch.stack([c, -s, s, c], -1).reshape(-1, 2, 2).double()
    cov = rot @ torch.diag_embed(sigma.double() ** 2) @ rot.transpose(1, 2) + 0.3 * torch.eye(2, dtype=torch.float64)
    inv = torch.linalg.inv(cov)
    conics = torch.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], -1).float()
    radii = torch.ceil(3 * torch.diagonal(cov, dim1=1, dim2=2).sqrt()).int()  # [N, 2]
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
    n = 20  # saturated opacities (0.999 clamp active near the centres)
    add(n, rand(n, 2) * size, 1 + 2 * rand(n, 2), 1 - 0.0005 * rand(n))
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
