"""Pruning a trained run by spatio-temporal significance, with a short recovery fine-tune.

A Gaussian's significance is LightGaussian's global significance (Fan et al. 2023) extended over
time, as Light4GS does for dynamic Gaussians (docs/pruning.md): the sum, over every training
camera and every training frame, of its blending weight w = α T (opacity × falloff ×
transmittance, ``ftgspp/render/contract.py``) at every pixel it touches. It is what the
renderer already computes: the render of all-ones colours is Σ_i w_i per pixel, so its pixel
sum's gradient with respect to Gaussian i's colour is Σ_pixels w_i (one render and one backward
pass a view, on any backend; no kernel changes).
A Gaussian hidden behind opaque ones, outside every view or alive only outside the clip scores 0.

Pruning keeps the top fraction F by significance (ties: the lower index), then fine-tunes
the kept Gaussians for a stated number of iterations with the run's own loss, optimiser,
colour correction and learning rates (the schedule continued past the run's end; no
relocation), and evaluates the held-out views as training does (``ftgspp.evaluate``).

    scores = significance(model, scene, backend="cpu")       # [N] float64
    keep = keep_top(scores, 0.34)                            # [N] bool
    results = prune_run("outputs/run", keep=0.34)            # ftgspp prune outputs/run --keep 0.34
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from ftgspp.checkpoint import load_colour_correction, load_run, run_scene, save_config, save_model
from ftgspp.colour_correction import ColorCorrection
from ftgspp.config import TrainConfig, cc_start
from ftgspp.data.scene import Camera, Scene
from ftgspp.errors import InputError
from ftgspp.evaluate import HeldOutRenders, evaluate, evaluate_lpips
from ftgspp.methods.base import DynamicGaussians
from ftgspp.runtime import enter, needs_child
from ftgspp.strategy import Relocator
from ftgspp.tracker import NullTracker
from ftgspp.train_state import FrameSampler, TrainState, make_optimizer, scene_extent
from ftgspp.trainer import _lpips_loss_net, _loop  # the run's own loop and loss, continued
from ftgspp.view import render_view

RESULTS = "prune.json"
SCORES = "significance.npy"
RECOVER_SHARE = 0.1  # default recovery: 10 % of the run's iterations


def view_significance(model: DynamicGaussians, cam: Camera, t: float, backend: str = "auto") -> torch.Tensor:
    """Σ over the pixels of camera ``cam`` at time ``t`` of each Gaussian's blending weight α T, ``[N]``
    (float32, on the model's device): the gradient of the all-ones render's pixel sum."""
    ones = torch.ones(len(model), 1, device=model.params["means"].device, requires_grad=True)  # [N, 1]
    out, _ = render_view(model, cam, t, 0, background=None, backend=backend, colors=ones)
    (grad,) = torch.autograd.grad(out.image.sum(), ones)  # only to the colours: no parameter gradients
    return grad[:, 0]


def significance(model: DynamicGaussians, scene: Scene, backend: str = "auto") -> torch.Tensor:
    """Spatio-temporal significance ``[N]`` (float64, CPU): Σ over the training cameras and frames of
    ``view_significance`` (held-out cameras never count)."""
    total = torch.zeros(len(model), dtype=torch.float64)
    for cam_idx in scene.train_ids:
        for t in scene.times:
            total += view_significance(model, scene.cameras[cam_idx], float(t), backend).detach().cpu().double()
    return total


def kept_count(n: int, fraction: float) -> int:
    """How many of ``n`` Gaussians the fraction ``fraction`` in (0, 1] keeps: ⌈F n⌉, at least one."""
    if not 0.0 < fraction <= 1.0:
        raise InputError("--keep", f"must be in (0, 1], got {fraction}")
    if n == 0:
        return 0
    return min(n, max(1, math.ceil(fraction * n - 1e-9)))  # 1e-9: 0.3 x 10 keeps 3, not 4


def keep_top(scores: torch.Tensor, fraction: float) -> torch.Tensor:
    """``[N]`` bool: the ``kept_count`` most significant of ``scores [N]``; equal scores keep the
    lower index (a stable sort), so the choice is the same on every machine for the same scores."""
    n = int(scores.shape[0])
    order = np.argsort(-scores.detach().cpu().double().numpy(), kind="stable")
    keep = torch.zeros(n, dtype=torch.bool)
    keep[torch.from_numpy(order[: kept_count(n, fraction)])] = True
    return keep


def recovery_config(cfg: TrainConfig, iterations: int, out_dir: Path) -> TrainConfig:
    """``cfg`` for ``iterations`` more steps after the run's last: the decaying learning rates go on
    along the run's exponential schedule (rate at step s: initial × ratio^(s / run iterations)), the
    colour correction stays on, relocation stays off, checkpoints go to ``out_dir``."""
    total = cfg.iterations + iterations
    lr = cfg.lr
    if cfg.iterations > 0:  # ratio' ^ (s / total) = ratio ^ (s / cfg.iterations)
        lr = replace(cfg.lr, means_final_ratio=cfg.lr.means_final_ratio ** (total / cfg.iterations))
    return replace(
        cfg, iterations=total, lr=lr, out_dir=str(out_dir),
        model=replace(cfg.model, cc_start_iter=cc_start(cfg)),
        strategy=replace(cfg.strategy, refine_stop_iter=min(cfg.strategy.refine_stop_iter, cfg.iterations)),
    )  # fmt: skip


def recover(model: DynamicGaussians, cc: ColorCorrection | None, scene: Scene, cfg: TrainConfig, iterations: int,
            out_dir: Path) -> float:
    """Fine-tune ``model`` (and ``cc``) in place for ``iterations`` steps with the trainer's loop
    (``recovery_config``; a fresh Adam, frames in a shuffle seeded by the run seed); returns the seconds."""
    if iterations <= 0:
        return 0.0
    rcfg = recovery_config(cfg, iterations, out_dir)
    device = model.params["means"].device
    relocator = Relocator(rcfg.strategy)
    extent = scene_extent(scene)
    state = TrainState(
        model=model, cc=cc, optimizer=make_optimizer(model, cc, rcfg, extent), relocator=relocator,
        reloc_stats=relocator.initialize_state(len(model), device),
        sampler=FrameSampler(scene, torch.Generator().manual_seed(cfg.seed)),
        reloc_gen=torch.Generator().manual_seed(cfg.seed + 1), extent=extent, step=cfg.iterations,
    )  # fmt: skip
    torch.manual_seed(cfg.seed)  # random backgrounds, as in training
    _loop(rcfg, scene, state, NullTracker(), out_dir, _lpips_loss_net(rcfg, device))
    return state.elapsed


def default_out(run_dir: Path, keep: float, recover_iterations: int) -> Path:
    """Where ``prune_run`` writes unless told: ``RUN/pruned/keep<F>_recover<N>``."""
    return run_dir / "pruned" / f"keep{keep:g}_recover{recover_iterations}"


def _original_metrics(run_dir: Path) -> dict[str, float]:
    """The run's own held-out metrics (its metrics.json), where it has them."""
    path = run_dir / "metrics.json"
    if not path.is_file():
        return {}
    saved = json.loads(path.read_text())
    names = ("psnr", "psnr_cc", "ssim1", "ssim2", "lpips_alex", "lpips_vgg", "n_gaussians")
    return {k: float(saved[k]) for k in names if k in saved}


def prune_run(run_dir: str | Path, keep: float, recover_iterations: int | None = None,
              out_dir: str | Path | None = None, data: str | None = None, backend: str | None = None) -> dict:
    """Prune the finished run in ``run_dir`` to the fraction ``keep`` of its Gaussians by significance,
    fine-tune ``recover_iterations`` steps (default 10 % of the run's), evaluate on the held-out views.

    Writes to ``out_dir`` (default ``default_out``) a loadable run (config.json, gaussians.pt, colour
    correction, metrics.json: ``ftgspp diagnose`` reads it), ``significance.npy`` ``[N]`` (the
    unpruned model's scores) and ``prune.json``, the dict returned: ``metrics`` (the pruned and
    recovered model's, flat, with ``n_gaussians``), ``before_recovery`` (the pruned model's core
    metrics), ``original`` (the run's metrics.json), counts, settings and seconds. ``InputError``
    for a missing run, a fraction outside (0, 1] or a negative recovery.
    """
    run = Path(run_dir)
    if not run.is_dir():
        raise InputError(run, "no such run folder")
    kept_count(1, keep)  # the fraction is checked before anything loads
    model, cfg = load_run(run)
    if recover_iterations is None:
        recover_iterations = int(round(RECOVER_SHARE * cfg.iterations))
    if recover_iterations < 0:
        raise InputError("--recover", f"must be >= 0 iterations, got {recover_iterations}")
    out = Path(out_dir) if out_dir is not None else default_out(run, keep, recover_iterations)
    backend = backend or ("auto" if cfg.backend == "gsplat" else cfg.backend)  # a GPU run on a CPU machine
    scene = run_scene(cfg, data)
    cfg = replace(cfg, out_dir=str(out), backend=backend)
    # This process's environment: a run trained in another determinism domain is pruned in this one.
    env = enter(replace(cfg, determinism="default", dispatch="native") if needs_child(cfg) else cfg)
    model = model.to(env.device)
    cc = load_colour_correction(run, cfg, len(scene.train_ids), env.device)
    out.mkdir(parents=True, exist_ok=True)

    clock = time.perf_counter()
    scores = significance(model, scene, backend)
    score_seconds = time.perf_counter() - clock
    np.save(out / SCORES, scores.numpy())
    mask = keep_top(scores, keep)
    pruned = model.subset(mask.to(model.params["means"].device))
    del model
    before, _ = evaluate(pruned, scene, cfg, out, n_saved=0)
    recover_seconds = recover(pruned, cc, scene, cfg, recover_iterations, out)

    save_config(cfg, out)
    save_model(pruned, cc, out)
    clock = time.perf_counter()
    renders = HeldOutRenders(pruned, scene, cfg)
    metrics, _ = evaluate(pruned, scene, cfg, out, renders=renders)
    metrics.update(evaluate_lpips(pruned, scene, cfg, renders=renders))
    metrics["n_gaussians"] = float(len(pruned))
    eval_seconds = time.perf_counter() - clock
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))

    total = float(scores.sum())
    results = {
        "run": str(run), "out_dir": str(out), "keep": keep, "recover_iterations": recover_iterations,
        "run_iterations": cfg.iterations, "backend": backend, "device": str(env.device),
        "n_before": int(mask.numel()), "n_after": int(mask.sum()),
        "n_zero_significance": int((scores == 0).sum()),
        "kept_significance_share": float(scores[mask].sum()) / total if total > 0 else float("nan"),
        "views_scored": len(scene.train_ids) * scene.n_frames,
        "metrics": metrics, "before_recovery": before, "original": _original_metrics(run),
        "seconds": {"significance": score_seconds, "recovery": recover_seconds, "evaluation": eval_seconds},
        "determinism": env.domain,
    }  # fmt: skip
    (out / RESULTS).write_text(json.dumps(results, indent=2))
    return results


def summary_line(results: dict) -> str:
    """One line: counts, recovery and the held-out metrics of the run, after pruning and recovery,
    and after pruning alone."""
    m, orig, pre = results["metrics"], results["original"], results["before_recovery"]

    def change(key: str) -> str:
        unit = " dB" if key.startswith("psnr") else ""
        was = f"{orig[key]:.3f} -> " if key in orig else ""
        return f"{key} {was}{m[key]:.3f}{unit} ({pre[key]:.3f} before recovery)"

    parts = [change(k) for k in ("psnr", "psnr_cc", "ssim1") if k in m]
    parts += [f"{k} {orig[k]:.4f} -> {m[k]:.4f}" if k in orig else f"{k} {m[k]:.4f}"
              for k in ("lpips_alex", "lpips_vgg") if k in m]
    return (f"pruned {results['run']}: {results['n_before']} -> {results['n_after']} Gaussians"
            f" (keep {results['keep']:g}, {results['kept_significance_share']:.1%} of the significance),"
            f" {results['recover_iterations']} recovery iterations; {', '.join(parts)};"
            f" results in {Path(results['out_dir']) / RESULTS}")
