"""The gsplat path against the ``reference`` renderer and gsplat's own relocation, on any device.

``ftgspp check-gpu`` runs this suite on the real CUDA kernels; the CPU test suite and
``scripts/gpu_check.sh --dry-run`` run it on CPU tensors with gsplat's CUDA ops replaced by the
torch stand-ins of ``tests/render/gsplat_standins.py``. Three checks, each a dict of largest
differences plus ``passed``:

- ``render_parity``: ``gsplat_adapter.render`` (gsplat's fused projection and tile rasterizer)
  against ``reference`` on ``parity_scene`` -- image, alpha, depth, every gradient, radii, and the
  culled Gaussians' outputs (uninitialised memory on a GPU) masked to finite zeros;
- ``raster_parity``: the bench's 2D rasterizer (``gsplat_adapter.rasterize``) against
  ``reference.rasterize`` on ``ftgspp bench render``'s scene;
- ``relocation_parity``: this project's MCMC relocation against gsplat's
  ``strategy.ops.relocate`` (its ``relocation`` kernel): same parameters, same Adam moments.

    python -c "from harness.run.gpu_parity import suite; print(suite('cuda'))"
"""

from __future__ import annotations

import math
from typing import Any
from unittest import mock

import torch

IMAGE_TOLERANCE = 1e-5  # image, alpha, depth (relative to its largest value)
GRAD_TOLERANCE = 1e-4  # each gradient, relative to the largest entry of the reference's
RELOCATION_TOLERANCE = 1e-5  # parameters after relocation, relative; Adam moments the same


def parity_scene(device: torch.device | str, seed: int = 0, n: int = 400) -> dict[str, torch.Tensor]:
    """Random Gaussians plus the cases culling must get right (near plane, behind the camera,
    off-screen, saturated and sub-1/255 opacities), on ``device``."""
    g = torch.Generator().manual_seed(seed)
    z = 1.5 + 4 * torch.rand(n, generator=g)
    xy = (torch.rand(n, 2, generator=g) * 2 - 1) * torch.tensor([0.75, 0.55]) * z[:, None]
    means = torch.cat([xy, z[:, None]], -1)
    means[:4] = torch.tensor([[0.0, 0.0, 0.01], [0.001, 0.0, 0.0099], [0.2, 0.1, -2.0], [0.0, 0.0, 0.0]])
    means[4:10, 0] = torch.tensor([-3.0, -2.2, 2.3, 3.2, -2.5, 2.6]) * means[4:10, 2]
    opacities = 0.05 + 0.9 * torch.rand(n, generator=g)
    opacities[10:16] = torch.tensor([1.0, 0.9995, 0.999, 0.0035, 0.0039, 0.004])
    scene = dict(means=means, quats=torch.randn(n, 4, generator=g), scales=0.02 + 0.12 * torch.rand(n, 3, generator=g),
                 opacities=opacities, colors=torch.rand(n, 3, generator=g))  # fmt: skip
    return {k: v.to(device) for k, v in scene.items()}


def parity(device: torch.device | str, width: int = 96, height: int = 72) -> dict[str, float]:
    """Largest differences between the gsplat adapter and ``reference`` on ``parity_scene``:
    image/alpha/depth (depth relative to its largest value), each gradient relative to the
    largest entry of the reference's, radii mismatches, and the culled Gaussians' outputs
    that are not exactly zero (``culled_nonzero``; the adapter must mask gsplat's
    uninitialised memory) or not finite."""
    from ftgspp.render import gsplat_adapter, render

    scene = parity_scene(device)
    viewmat = torch.eye(4, device=device)
    K = torch.tensor([[78.0, 0.0, (width - 1) / 2], [0.0, 75.0, (height - 1) / 2], [0.0, 0.0, 1.0]], device=device)
    bg = torch.tensor([0.1, 0.3, 0.6], device=device)
    results = {}
    for name in ("gsplat", "reference"):
        leaves = {k: v.clone().requires_grad_(True) for k, v in scene.items()}
        args = (*leaves.values(), viewmat, K, width, height, bg)
        out = gsplat_adapter.render(*args, 0.01) if name == "gsplat" else render(*args, backend="reference")
        g = torch.Generator().manual_seed(5)
        cot = [torch.randn(t.shape, generator=g).to(device) for t in (out.image, out.alpha, out.depth)]
        torch.autograd.backward([out.image, out.alpha, out.depth], cot)
        results[name] = (out, {k: v.grad for k, v in leaves.items()})
    (out, grads), (ref, ref_grads) = results["gsplat"], results["reference"]
    culled = (out.radii == 0).any(-1)
    diffs = {"radii_mismatch": float((out.radii != ref.radii).any(-1).sum()), "culled": float(culled.sum())}
    diffs["culled_nonzero"] = float((out.means2d[culled] != 0).any(-1).sum())
    diffs["nonfinite"] = float(sum(int((~torch.isfinite(t)).sum()) for t in (out.means2d, out.depths, *grads.values())))
    for name in ("image", "alpha", "depth"):
        want = getattr(ref, name)
        scale = max(1.0, want.abs().max().item()) if name == "depth" else 1.0
        diffs[name] = (getattr(out, name) - want).abs().max().item() / scale
    for name, want in ref_grads.items():
        diffs[f"grad_{name}"] = ((grads[name] - want).abs().max() / want.abs().max().clamp_min(1e-12)).item()
    return diffs


def parity_passes(diffs: dict[str, float]) -> bool:
    """Whether ``parity``'s differences are within the tolerances of the module docstring."""
    exact = ("radii_mismatch", "culled", "culled_nonzero", "nonfinite")
    return (diffs["radii_mismatch"] == 0 and diffs.get("culled_nonzero", 0) == 0 and diffs.get("nonfinite", 0) == 0
            and all(v <= (GRAD_TOLERANCE if k.startswith("grad_") else IMAGE_TOLERANCE)
                    for k, v in diffs.items() if k not in exact))  # fmt: skip


def render_parity(device: torch.device | str) -> dict[str, Any]:
    """``parity`` plus its verdict, ``passed``."""
    diffs = parity(device)
    return {**diffs, "passed": parity_passes(diffs)}


def raster_parity(device: torch.device | str, n: int = 300, width: int = 80, height: int = 56) -> dict[str, Any]:
    """The bench's gsplat rasterizer against ``reference.rasterize`` on the bench's projected
    scene: largest image/alpha/depth difference and worst relative gradient, ``passed``."""
    from ftgspp.bench.random_scene import project_scene, random_scene
    from ftgspp.render import gsplat_adapter
    from ftgspp.render.reference import rasterize as reference_rasterize

    inputs = project_scene(random_scene(n, width, height))
    names = ("means2d", "conics", "colors", "opacities", "depths")
    outs = {}
    for key, fn in (("gsplat", gsplat_adapter.rasterize), ("reference", reference_rasterize)):
        leaves = {k: inputs[k].to(device).clone().requires_grad_(True) for k in names}
        image, alpha, depth = fn(*leaves.values(), inputs["radii"].to(device), width, height,
                                 inputs["background"].to(device))  # fmt: skip
        (image.sum() + 0.5 * alpha.sum() + 0.1 * depth.sum()).backward()
        outs[key] = ((image, alpha, depth), {k: v.grad for k, v in leaves.items()})
    (got, grads), (want, ref_grads) = outs["gsplat"], outs["reference"]
    result = {"image": max((a - b).abs().max().item() for a, b in zip(got, want))}
    result["grad"] = max(((grads[k] - ref_grads[k]).abs().max() / ref_grads[k].abs().max().clamp_min(1e-12)).item()
                         for k in names)  # fmt: skip
    result["passed"] = result["image"] <= IMAGE_TOLERANCE and result["grad"] <= GRAD_TOLERANCE
    return result


def relocation_parity(device: torch.device | str, n: int = 40) -> dict[str, Any]:
    """This project's MCMC relocation and gsplat's ``strategy.ops.relocate`` on the same dead
    Gaussians and sources (two of them shared by 3 and 4 copies: Eq. 9's n > 1), after three
    Adam steps: the largest relative parameter difference, the largest Adam-moment difference,
    whether the destinations keep their second moments (gsplat does), ``passed``."""
    from gsplat.strategy import ops as gs_ops
    from torch import nn

    import ftgspp.strategy.relocate as ours
    from ftgspp.config import StrategyConfig
    from ftgspp.strategy import Relocator

    g = torch.Generator().manual_seed(0)
    init = {
        "means": torch.randn(n, 3, generator=g), "scales": torch.randn(n, 3, generator=g) - 2,
        "quats": torch.randn(n, 4, generator=g), "opacities": torch.randn(n, generator=g),
        "velocities": torch.randn(n, 3, generator=g),
    }  # fmt: skip
    init["opacities"][:6] = -9.0  # dead
    dead = torch.arange(6)
    sources = torch.tensor([10, 10, 17, 25, 25, 25])

    def trained(single: bool):
        params = nn.ParameterDict({k: nn.Parameter(v.clone().to(device)) for k, v in init.items()})
        if single:  # the trainer's one optimizer with a group per parameter
            opts = torch.optim.Adam([{"params": [p], "name": k} for k, p in params.items()], lr=1e-2)
        else:  # gsplat's dict of optimizers
            opts = {k: torch.optim.Adam([p], lr=1e-2) for k, p in params.items()}
        for step in range(3):
            loss = sum(((p - 0.1 * step) ** 2).sum() for p in params.values())
            loss.backward()
            for o in [opts] if single else opts.values():
                o.step()
                o.zero_grad()
        return params, opts

    params, opt = trained(single=True)
    with mock.patch.object(ours, "choose_relocation", lambda *a, **k: (dead, sources)):
        relocator = Relocator(StrategyConfig(relocation="mcmc"))
        relocator.step(params, opt, relocator.initialize_state(n, device), torch.Generator())
    gs_params, gs_opts = trained(single=False)
    picks = torch.searchsorted(torch.arange(6, n), sources).to(device)  # the sources among the alive ones
    binoms = torch.tensor([[math.comb(a, b) if b <= a else 0 for b in range(51)] for a in range(51)],
                          dtype=torch.float32, device=device)  # fmt: skip
    mask = torch.zeros(n, dtype=torch.bool, device=device)
    mask[dead] = True
    with mock.patch.object(gs_ops, "_multinomial_sample", lambda probs, k, replacement=True: picks):
        gs_ops.relocate(gs_params, gs_opts, {}, mask, binoms, min_opacity=StrategyConfig().min_opacity)
    param_diff, moment_diff = 0.0, 0.0
    for name in init:
        a, b = params[name].detach(), gs_params[name].detach()
        param_diff = max(param_diff, ((a - b).abs() / (b.abs() + 1e-6)).max().item())
        for key in ("exp_avg", "exp_avg_sq"):
            ours_m, gs_m = opt.state[params[name]][key], gs_opts[name].state[gs_params[name]][key]
            moment_diff = max(moment_diff, (ours_m - gs_m).abs().max().item())
    kept = bool((opt.state[params["means"]]["exp_avg_sq"][dead.to(device)] > 0).all())  # as in gsplat
    return {"params": param_diff, "moments": moment_diff, "destination_moments_kept": kept,
            "passed": param_diff <= RELOCATION_TOLERANCE and moment_diff <= 1e-7 and kept}  # fmt: skip


def suite(device: torch.device | str) -> dict[str, dict[str, Any]]:
    """Every check of this module on ``device``; a check that raises is recorded as failed."""
    out: dict[str, dict[str, Any]] = {}
    for name, check in (("render", render_parity), ("raster", raster_parity), ("relocation", relocation_parity)):
        try:
            out[name] = check(device)
        except Exception as exc:  # a kernel error must not hide the other checks
            out[name] = {"passed": False, "error": f"{type(exc).__name__}: {exc}"[:400]}
    return out


def describe(results: dict[str, dict[str, Any]]) -> str:
    """One line per check of ``suite``'s results."""
    lines = []
    for name, r in results.items():
        verdict = "PASS" if r.get("passed") else "FAIL"
        if "error" in r:
            lines.append(f"parity {name}: FAIL: {r['error']}")
        elif name == "render":
            worst = max(v for k, v in r.items() if k.startswith("grad_"))
            lines.append(f"parity render: {verdict}: image {r['image']:.2g}, alpha {r['alpha']:.2g}, depth "
                         f"{r['depth']:.2g} (<= {IMAGE_TOLERANCE:g}), worst gradient {worst:.2g} (<= {GRAD_TOLERANCE:g}),"
                         f" radii mismatches {int(r['radii_mismatch'])}, culled {int(r['culled'])} (non-zero "
                         f"{int(r['culled_nonzero'])}, non-finite {int(r['nonfinite'])})")  # fmt: skip
        elif name == "raster":
            lines.append(f"parity bench rasterizer: {verdict}: image {r['image']:.2g}, worst gradient {r['grad']:.2g}")
        else:
            lines.append(f"parity relocation vs gsplat relocate: {verdict}: parameters {r['params']:.2g} "
                         f"(<= {RELOCATION_TOLERANCE:g}), Adam moments {r['moments']:.2g}")
    return "\n".join(lines)
