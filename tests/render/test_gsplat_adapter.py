"""The gsplat adapter's glue, without gsplat: where its requirements are checked, and what it
hands to gsplat and makes of gsplat's answers (a stand-in module records the calls).

gsplat itself (CUDA) is not installed here, so these tests pin the conventions the adapter
adds -- the +0.5 px pixel-centre shift, depth as one more channel, per-axis radii -- not
gsplat's numbers.
"""

from __future__ import annotations

import subprocess
import sys
import types

import pytest
import torch

from ftgspp.render import gsplat_adapter, resolve_backend


def test_gsplat_is_checked_at_backend_resolution() -> None:
    with pytest.raises(RuntimeError, match="'gsplat' needs CUDA tensors"):
        resolve_backend("gsplat", torch.device("cpu"))
    if "gsplat" not in sys.modules and not _installed():
        with pytest.raises(RuntimeError, match="'gsplat' is unavailable"):
            resolve_backend("gsplat", torch.device("cuda"))


def _installed() -> bool:
    import importlib.util

    return importlib.util.find_spec("gsplat") is not None


def test_importing_the_renderer_does_not_import_gsplat() -> None:
    code = "import sys, ftgspp.render, ftgspp.render.gsplat_adapter, ftgspp.bench; print('gsplat' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_a_missing_gsplat_is_a_runtime_error_naming_the_backend(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "gsplat", None)  # as if it were not installed
    with pytest.raises(RuntimeError, match="'gsplat' is unavailable"):
        gsplat_adapter.rasterize(torch.zeros(1, 2), torch.ones(1, 3), torch.ones(1, 3), torch.ones(1),
                                 torch.ones(1), torch.ones(1), 8, 8)  # fmt: skip


def test_render_shifts_the_principal_point_and_keeps_the_means2d_gradient(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = {}
    n, width, height = 3, 12, 10

    def rasterization(means, quats, scales, opacities, colors, viewmats, Ks, w, h, **kw):
        calls.update(Ks=Ks, viewmats=viewmats, size=(w, h), **kw)
        means2d = (means[:, :2] * 2.0).unsqueeze(0)  # [1, N, 2], in the graph of means
        rgbd = torch.arange(h * w * 4, dtype=torch.float32).reshape(1, h, w, 4) + means2d.sum()
        meta = {"means2d": means2d, "radii": torch.tensor([[[2, 5], [0, 0], [7, 1]]]), "depths": means[None, :, 2]}
        return rgbd, torch.full((1, h, w, 1), 0.5), meta

    monkeypatch.setitem(sys.modules, "gsplat", types.SimpleNamespace(rasterization=rasterization))
    means = torch.rand(n, 3, requires_grad=True)
    K = torch.tensor([[20.0, 0.0, 5.5], [0.0, 20.0, 4.5], [0.0, 0.0, 1.0]])
    out = gsplat_adapter.render(means, torch.rand(n, 4), torch.rand(n, 3), torch.rand(n), torch.rand(n, 3),
                                torch.eye(4), K, width, height, torch.tensor([0.1, 0.2, 0.3]), 0.05)  # fmt: skip
    assert calls["Ks"].shape == (1, 3, 3) and calls["Ks"][0, 0, 2] == 6.0 and calls["Ks"][0, 1, 2] == 5.0
    assert K[0, 2] == 5.5  # the caller's K is left alone
    assert calls["size"] == (width, height) and calls["near_plane"] == 0.05 and calls["eps2d"] == 0.3
    assert calls["tile_size"] == 16 and calls["render_mode"] == "RGB+D" and calls["backgrounds"].shape == (1, 3)
    assert out.image.shape == (height, width, 3) and out.depth.shape == (height, width, 1)
    assert out.radii.tolist() == [5, 0, 7]  # per-axis radii (gsplat >= 1.5): the larger one
    out.image.sum().backward()
    assert out.means2d.grad is not None and out.means2d.grad.shape == (n, 2)


def test_rasterize_hands_gsplat_half_integer_centres_and_depth_as_a_channel(monkeypatch: pytest.MonkeyPatch) -> None:
    calls = {}
    width, height = 40, 20  # 3 x 2 tiles

    def isect_tiles(means2d, radii, depths, tile_size, tiles_w, tiles_h):
        if radii.dim() != 3:  # like gsplat >= 1.5: per-axis radii only
            raise TypeError("radii must be [C, N, 2]")
        calls.update(means2d=means2d, radii=radii, tiles=(tile_size, tiles_w, tiles_h))
        return None, torch.zeros(1), torch.zeros(1)

    def rasterize_to_pixels(means2d, conics, feats, opacities, w, h, tile_size, offsets, flatten_ids, backgrounds):
        calls.update(feats=feats, backgrounds=backgrounds)
        return torch.ones(1, h, w, feats.shape[-1]) * torch.arange(feats.shape[-1]), torch.zeros(1, h, w, 1)

    fake = types.SimpleNamespace(isect_tiles=isect_tiles, rasterize_to_pixels=rasterize_to_pixels,
                                 isect_offset_encode=lambda ids, n, tw, th: torch.zeros(1, th, tw))  # fmt: skip
    monkeypatch.setitem(sys.modules, "gsplat", fake)
    means2d = torch.tensor([[3.0, 4.0], [10.0, 12.0]])
    colors, depths = torch.rand(2, 3), torch.tensor([2.0, 5.0])
    image, alpha, depth = gsplat_adapter.rasterize(means2d, torch.ones(2, 3), colors, torch.ones(2), depths,
                                                   torch.tensor([3, 4]), width, height, torch.tensor([0.1, 0.2, 0.3]))
    torch.testing.assert_close(calls["means2d"][0], means2d + 0.5)
    assert calls["radii"].tolist() == [[[3, 3], [4, 4]]] and calls["tiles"] == (16, 3, 2)
    torch.testing.assert_close(calls["feats"][0], torch.cat([colors, depths[:, None]], -1))
    torch.testing.assert_close(calls["backgrounds"], torch.tensor([[0.1, 0.2, 0.3, 0.0]]))
    assert image.shape == (height, width, 3) and alpha.shape == depth.shape == (height, width, 1)
    assert image[0, 0].tolist() == [0.0, 1.0, 2.0] and depth[0, 0].item() == 3.0  # the last channel is depth
