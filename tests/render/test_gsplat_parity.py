"""The gsplat backend against ``reference``, through gsplat 1.5.3's own Python code on CPU.

``gsplat_standins.install`` replaces gsplat's CUDA extension by torch versions of its ops that
follow the CUDA kernels' conventions; everything else -- ``gsplat.rasterization``,
``isect_tiles``, ``rasterize_to_pixels``, the autograd functions, ``strategy.ops.relocate`` --
is gsplat's code, driven by this project's adapters. So these tests show the backends agree
as they will on a GPU: the adapter's glue, and the conventions ``contract.py`` states.
"""

from __future__ import annotations

import pytest
import torch

from ftgspp.render import gsplat_adapter, render
from ftgspp.render.reference import rasterize as reference_rasterize
from harness.cli.check_gpu import parity_scene
from tests.render.cpu_scenes import assert_grad_close
from tests.render.gsplat_standins import install

W, H = 64, 48  # 4 x 3 tiles


@pytest.fixture
def gsplat(monkeypatch: pytest.MonkeyPatch):
    return install(monkeypatch)


def awkward_scene(seed: int = 0, n: int = 160) -> dict:
    """``ftgspp check-gpu``'s scene: random Gaussians plus the cases culling must get right (at
    and just short of the near plane, behind the camera, off-screen with some reaching in,
    saturated opacities for the 0.999 clamp, opacities below 1/255), and a background."""
    return parity_scene("cpu", seed, n) | {"background": torch.tensor([0.1, 0.3, 0.6])}


def camera() -> tuple[torch.Tensor, torch.Tensor]:
    viewmat = torch.eye(4)
    K = torch.tensor([[52.0, 0.0, 31.5], [0.0, 50.0, 23.5], [0.0, 0.0, 1.0]])
    return viewmat, K


def render_with(backend: str, scene: dict, module=None):
    """Render ``scene`` and backpropagate a fixed random projection of every output."""
    leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items() if k != "background"}
    viewmat, K = camera()
    args = (leaves["means"], leaves["quats"], leaves["scales"], leaves["opacities"], leaves["colors"], viewmat, K, W, H)
    if backend == "gsplat":  # the adapter itself: its CUDA check lives in resolve_backend
        out = gsplat_adapter.render(*args, scene["background"], 0.01)
    else:
        out = render(*args, scene["background"], backend=backend, near_plane=0.01)
    g = torch.Generator().manual_seed(5)
    cot = [torch.randn(t.shape, generator=g) for t in (out.image, out.alpha, out.depth)]
    torch.autograd.backward([out.image, out.alpha, out.depth], cot)
    grads = {k: v.grad for k, v in leaves.items()} | {"means2d": out.means2d.grad}
    return out, grads


def test_adapter_matches_reference_images_and_gradients(gsplat) -> None:
    scene = awkward_scene()
    out, grads = render_with("gsplat", scene)
    ref, ref_grads = render_with("reference", scene)
    visible = (ref.radii > 0).all(-1)
    assert visible[0] and not visible[1:4].any()  # on the near plane: kept; short of it, behind, at 0: culled
    assert not visible[13:15].any() and visible[15]  # below 1/255: culled
    assert torch.equal(out.radii, ref.radii)
    for name in ("image", "alpha", "depth"):  # depth is in scene units (up to ~5 here): relative
        scale = max(1.0, getattr(ref, name).abs().max().item())
        diff = (getattr(out, name) - getattr(ref, name)).abs().max().item()
        assert diff <= 1e-5 * scale, f"{name}: max difference {diff:.3g} (scale {scale:.3g})"
    assert (ref.alpha > 0.99).any() and (ref.alpha < 0.5).any()
    torch.testing.assert_close(out.means2d, ref.means2d, rtol=0, atol=1e-4)
    torch.testing.assert_close(out.depths, ref.depths, rtol=1e-6, atol=0)
    for name in ("means", "quats", "scales", "opacities", "colors", "means2d"):
        assert_grad_close(grads[name], ref_grads[name], name)


def test_cpu_backend_matches_the_adapter(gsplat) -> None:
    scene = awkward_scene(1)
    out, grads = render_with("gsplat", scene)
    cpu, cpu_grads = render_with("cpu", scene)
    assert torch.equal(out.radii, cpu.radii)
    assert (out.image - cpu.image).abs().max() <= 1e-5
    for name in ("means", "quats", "scales", "opacities", "colors"):
        assert_grad_close(cpu_grads[name], grads[name], name)


def test_culled_gaussians_come_back_finite(gsplat) -> None:
    """gsplat leaves culled entries uninitialised (NaN in the stand-in); the adapter masks them."""
    scene = awkward_scene(2)
    out, grads = render_with("gsplat", scene)
    culled = (out.radii == 0).any(-1)
    assert culled.sum() >= 5
    assert torch.isfinite(out.means2d).all() and torch.isfinite(out.depths).all()
    assert (out.means2d[culled] == 0).all() and (grads["means2d"][culled] == 0).all()
    assert all(torch.isfinite(g).all() for g in grads.values())


def test_bench_adapter_matches_reference(gsplat) -> None:
    """``ftgspp bench render``'s gsplat rasterizer on the bench's own projected scene."""
    from ftgspp.bench.random_scene import project_scene, random_scene

    inputs = project_scene(random_scene(300, 80, 56))
    names = ("means2d", "conics", "colors", "opacities", "depths")
    outs = {}
    for key, fn in (("gsplat", gsplat_adapter.rasterize), ("reference", reference_rasterize)):
        leaves = {k: inputs[k].clone().requires_grad_(True) for k in names}
        image, alpha, depth = fn(*leaves.values(), inputs["radii"], inputs["width"], inputs["height"],
                                 inputs["background"])  # fmt: skip
        (image.sum() + 0.5 * alpha.sum() + 0.1 * depth.sum()).backward()
        outs[key] = (image, alpha, depth, {k: v.grad for k, v in leaves.items()})
    for a, b in zip(outs["gsplat"][:3], outs["reference"][:3]):
        assert (a - b).abs().max() <= 1e-5
    for name in names:
        assert_grad_close(outs["gsplat"][3][name], outs["reference"][3][name], name)


def test_relocation_matches_gsplat_relocate(gsplat) -> None:
    """This project's MCMC relocation and gsplat's ``strategy.ops.relocate`` (the official code's)
    on the same dead Gaussians and sources (shared: n = 3 and 4 in Eq. 9): same parameters, the
    same Adam moments bit for bit, the destinations' moments kept. ``ftgspp check-gpu`` runs this
    very function on CUDA (``harness/run/gpu_parity.py``); here on CPU tensors."""
    from harness.run.gpu_parity import relocation_parity

    result = relocation_parity("cpu")
    assert result["params"] <= 1e-6 and result["moments"] == 0.0, result
    assert result["destination_moments_kept"] and result["passed"], result


def test_check_gpu_parity_step_passes_on_the_stand_ins(gsplat) -> None:
    """``ftgspp check-gpu`` runs this very function on CUDA; here it runs on CPU tensors."""
    from harness.cli.check_gpu import parity, parity_passes

    diffs = parity("cpu")
    assert parity_passes(diffs), diffs
    assert diffs["radii_mismatch"] == 0 and diffs["image"] <= 1e-5


def test_check_gpu_without_cuda_is_one_line_and_exit_2() -> None:
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "harness.cli.ftgspp_cmd", "check-gpu"], capture_output=True, text=True,
                          env={**__import__("os").environ, "CUDA_VISIBLE_DEVICES": ""})  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "no CUDA device" in proc.stderr
