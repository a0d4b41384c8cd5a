"""Spacetime Gaussians through the gsplat adapter, against ``reference``, on CPU.

As ``tests/render/test_gsplat_parity.py``: gsplat 1.5.3's own Python code with its CUDA ops
replaced by torch stand-ins, so the STGS model's Gaussians at a time t (moved by its cubic
motion, turned by its rotation speed, faded by its temporal RBF) render and backpropagate to
every STGS parameter as the reference renderer does.
"""

from __future__ import annotations

import torch

from ftgspp.render import gsplat_adapter, render
from tests.methods.test_stg import random_stg
from tests.render.cpu_scenes import assert_grad_close
from tests.render.gsplat_standins import install

W, H = 64, 48


def render_stg(backend: str, t: float) -> tuple[object, dict[str, torch.Tensor]]:
    model = random_stg(n=150, seed=4)
    viewmat = torch.eye(4)
    K = torch.tensor([[52.0, 0.0, 31.5], [0.0, 50.0, 23.5], [0.0, 0.0, 1.0]])
    g = model.at_time(t)
    args = (g.means, g.quats, g.scales, g.opacities, g.colors, viewmat, K, W, H)
    background = torch.tensor([0.1, 0.3, 0.6])
    if backend == "gsplat":
        out = gsplat_adapter.render(*args, background, 0.01)
    else:
        out = render(*args, background, backend=backend, near_plane=0.01)
    gen = torch.Generator().manual_seed(5)
    cot = [torch.randn(x.shape, generator=gen) for x in (out.image, out.alpha, out.depth)]
    torch.autograd.backward([out.image, out.alpha, out.depth], cot)
    return out, {k: p.grad for k, p in model.params.items()}


def test_gsplat_adapter_renders_stgs_like_the_reference(monkeypatch) -> None:
    install(monkeypatch)
    for t in (0.2, 0.8):
        out, grads = render_stg("gsplat", t)
        ref, ref_grads = render_stg("reference", t)
        assert torch.equal(out.radii, ref.radii) and (ref.alpha > 0.5).any()
        for name in ("image", "alpha"):
            diff = (getattr(out, name) - getattr(ref, name)).abs().max().item()
            assert diff <= 1e-5, f"{name} at t={t}: max difference {diff:.3g}"
        for name, expected in ref_grads.items():
            assert expected is not None and expected.abs().max() > 0, name
            assert_grad_close(grads[name], expected, f"{name} at t={t}")
