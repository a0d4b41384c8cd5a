"""The other stages of a ``cpu`` training render, each timed against what it replaces.

``prepare``: time evaluation + SH colour + projection, PyTorch autograd against the fused
Numba node; ``ssim_loss``: 1 - SSIM, grouped ``conv2d`` against the Numba kernels. Both
forward + backward, on a model whose Gaussians at t = 0.5 are the bench's random scene.
"""

from __future__ import annotations

import statistics
import time
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor

if TYPE_CHECKING:
    from ftgspp.methods.freetime import FreeTimeGaussians


def stage_model(scene: dict[str, Any], seed: int) -> "FreeTimeGaussians":
    """A FreeTimeGS++ model (gate on, max_duration 1 s, SH degree 3) whose Gaussians at t = 0.5
    are ``scene``'s 3D Gaussians (the bench camera sits at the world origin)."""
    from ftgspp.config import ModelConfig
    from ftgspp.methods.freetime import FreeTimeGaussians

    g = torch.Generator().manual_seed(seed + 2)
    n = scene["means"].shape[0]
    times = torch.rand(n, generator=g)
    velocities = 0.05 * torch.randn(n, 3, generator=g)
    params = {
        "means": scene["means"] - velocities * (0.5 - times)[:, None],
        "velocities": velocities,
        "times": times,
        "durations": torch.randn(n, generator=g),
        "scales": torch.log(scene["scales"]),
        "quats": scene["quats"],
        "opacities": torch.logit(scene["opacities"].clamp(1e-4, 1 - 1e-4)),
        "sh0": ((scene["colors"] - 0.5) / 0.28209479177387814)[:, None, :],
        "shN": 0.05 * torch.randn(n, 15, 3, generator=g),
        "gates": -1.0 + 0.1 * torch.randn(n, generator=g),
    }
    return FreeTimeGaussians(params, ModelConfig(max_duration=1.0, gate=True))


def time_stages(scene: dict[str, Any], repeats: int, seed: int = 0) -> dict[str, dict[str, float]]:
    """Median forward + backward milliseconds of the other stages of a ``cpu`` training render.

    ``prepare``: time evaluation + SH colour (degree 3) + EWA projection, as PyTorch autograd
    (``at_time``, ``eval_sh``, ``project``: the ``reference`` path) and as the fused Numba node.
    ``ssim_loss``: 1 - SSIM of a rendered-size image, grouped ``conv2d`` vs the Numba kernels.
    """
    from ftgspp.image_metrics import SSIM_WINDOW, _nchw, _ssim_map, ssim_same
    from ftgspp.methods.freetime_fused import prepare
    from ftgspp.render.contract import CameraTensors
    from ftgspp.render.project import project
    from ftgspp.render.sh import eval_sh

    model = stage_model(scene, seed)
    params, width, height = model.params, scene["width"], scene["height"]
    viewmat, K, centre = scene["viewmat"], scene["K"], torch.zeros(3)
    camera = CameraTensors(viewmat, K, centre, width, height)
    g = torch.Generator().manual_seed(seed + 3)
    n = len(model)
    cot = [torch.randn(n, k, generator=g) for k in (2, 3, 3)] + [torch.randn(n, generator=g) for _ in range(2)]

    def weighted(outputs: tuple[Tensor, ...]) -> Tensor:
        return sum((o * c).sum() for o, c in zip(outputs, cot))

    def autograd_prepare() -> None:
        at = model.at_time(0.5)
        dirs = at.means - centre
        colors = eval_sh(3, at.sh, dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-8))
        means2d, conics, depths, _, _ = project(at.means, at.quats, at.scales, viewmat, K, width, height)
        weighted((means2d, conics, colors, at.opacities, depths)).backward()

    def fused_prepare() -> None:
        p = prepare(params, 0.5, camera, 3, 1.0, True, model.cfg.gate_gamma)
        weighted((p.means2d, p.conics, p.colors, p.opacities, p.depths)).backward()

    pred = torch.rand(height, width, 3, generator=g).requires_grad_(True)
    gt = torch.rand(height, width, 3, generator=g)

    def conv_ssim() -> None:
        ssim = _ssim_map(_nchw(pred[None]), _nchw(gt[None]), 1.0, padding=SSIM_WINDOW // 2).mean()
        (1.0 - ssim).backward()

    def numba_ssim() -> None:
        (1.0 - ssim_same(pred, gt)).backward()

    stages = {"prepare": {"autograd": autograd_prepare, "fused": fused_prepare},
              "ssim_loss": {"conv2d": conv_ssim, "numba": numba_ssim}}  # fmt: skip
    samples: dict[str, dict[str, list[float]]] = {k: {v: [] for v in fns} for k, fns in stages.items()}
    for r in range(repeats + 2):  # the first two are warm-up
        for stage, fns in stages.items():
            for variant, fn in fns.items():
                t0 = time.perf_counter()
                fn()
                if r >= 2:
                    samples[stage][variant].append(1e3 * (time.perf_counter() - t0))
        for p in [*params.values(), pred]:
            p.grad = None
    return {stage: {f"{v}_ms": statistics.median(t) for v, t in variants.items()}
            for stage, variants in samples.items()}  # fmt: skip
