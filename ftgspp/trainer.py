"""``train(cfg, scene, tracker)``: the optimisation loop of every method (FreeTimeGS(++), STGS, yours).

One iteration: pick a (training camera, frame) pair from a seeded shuffle, evaluate the
method's Gaussians (``ftgspp/methods``) at that frame's time, render, compute the loss of docs/design.md §4
(``loss_terms``), backpropagate, take one Adam step over every parameter group, and every
``refine_every`` iterations relocate dead Gaussians. Everything the loop mutates lives in
one ``TrainState`` (``ftgspp/train_state.py``); checkpoints go to
``<out_dir>/checkpoint.pt`` and a re-run with the same ``out_dir`` resumes from it.
Evaluation on the held-out cameras ends the run, then the diagnostics. The run's environment
(determinism mode, threads, Numba, device) is set by ``ftgspp.runtime.enter``; a run whose
determinism mode or kernel dispatch this process cannot have trains in a child process
(``ftgspp.runtime.child``, started as ``python -m ftgspp.trainer CONFIG``).

Run it from the command line with ``ftgspp train [overrides]``; call ``train`` directly
in Python (the tests do).
"""

from __future__ import annotations

import json
import logging
import math
import resource
import time
from pathlib import Path

import torch
from tqdm import tqdm

from ftgspp.checkpoint import save_config, save_model
from ftgspp.colour_correction import ColorCorrection
from ftgspp.config import TrainConfig, cc_start
from ftgspp.data.scene import Scene
from ftgspp.diagnostics.diagnose import run_diagnostics
from ftgspp.errors import InputError
from ftgspp.evaluate import HeldOutRenders, check_eval_lpips, evaluate, evaluate_lpips
from ftgspp.image_metrics import lpips_distance
from ftgspp.losses import logged_photometric, photometric
from ftgspp.methods import method_class
from ftgspp.methods.base import DynamicGaussians, GaussiansAt
from ftgspp.optim import adam_step, clear_grads, plain_fused_adam
from ftgspp.render import BACKENDS
from ftgspp.runtime import enter, needs_child, train_in_child
from ftgspp.runtime.child import check_dispatch
from ftgspp.runtime.determinism import MODES
from ftgspp.strategy import Relocator
from ftgspp.tracker import NullTracker, RunResult, Tracker
from ftgspp.train_state import INIT_SPACINGS, TrainState, set_learning_rates
from ftgspp.view import render_view

log = logging.getLogger("ftgspp.train")

CHECKPOINT = "checkpoint.pt"


class Diverged(Exception):
    """The loss became NaN or Inf at iteration ``step`` after ``seconds`` of training."""

    def __init__(self, step: int, seconds: float, loss: float) -> None:
        super().__init__(f"loss is {loss} at iteration {step}")
        self.step, self.seconds = step, seconds


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def loss_terms(
    cfg: TrainConfig,
    model: DynamicGaussians,
    g: GaussiansAt,
    image: torch.Tensor,  # [H, W, 3] render (after colour correction when it is on)
    gt: torch.Tensor,  # [H, W, 3]
    cc: ColorCorrection | None = None,  # only while the correction is switched on
    lpips_net: torch.nn.Module | None = None,
) -> dict[str, torch.Tensor]:
    """The training loss of docs/design.md §4, term by term; ``"total"`` is their weighted sum.

    With the weights of ``cfg.loss`` (λ = ``ssim``):

    total = photometric [(1 − λ) L1 + λ (1 − SSIM)] + lpips · LPIPS-alex
            + the method's regularizers [+ cc_reg · Σ(‖ΔM‖² + ‖b‖²)]

    FreeTimeGS's regularizers (``FreeTimeGaussians.regularizers``) are opacity_reg ·
    mean(σ(o) φ(t).detach()) + scale_reg · mean(exp S) [+ gate_reg · mean(1 − g)].
    """
    w = cfg.loss
    photo, l1 = photometric(image, gt, w.ssim)
    terms = {"photometric": photo, "l1": l1}
    total = photo
    if lpips_net is not None:  # LPIPS with the correct [-1, 1] inputs
        terms["lpips"] = lpips_distance(lpips_net, image.clamp(0, 1), gt)
        total = total + w.lpips * terms["lpips"]
    for name, weight, value in list(model.regularizers(g, w)):  # every term, then their weighted sum
        terms[name] = value
        total = total + weight * value
    if cc is not None:
        terms["cc"] = cc.regularizer()
        total = total + w.cc_reg * terms["cc"]
    terms["total"] = total
    return terms


def sh_degree_at(cfg: TrainConfig, it: int) -> int:
    """SH degree used at iteration ``it`` (0-based): one more every ``sh_degree_interval``."""
    return min(cfg.model.sh_degree, it // max(cfg.sh_degree_interval, 1))


def check_config(cfg: TrainConfig) -> None:
    """Every check of ``cfg`` that needs no scene and writes nothing; one-line ``InputError``."""
    check_eval_lpips(cfg.eval_lpips)
    check_dispatch(cfg)
    method_class(cfg.model.method)  # unknown or unimportable method
    if cfg.determinism not in MODES:
        raise InputError("determinism", f"unknown mode '{cfg.determinism}' (choose from {', '.join(MODES)})")
    Relocator(cfg.strategy)  # unknown relocation policy or clamp rule
    if cfg.model.cc_gauge not in ColorCorrection.GAUGES:
        raise InputError("model.cc_gauge", f"unknown gauge '{cfg.model.cc_gauge}' (choose from"
                         f" {', '.join(ColorCorrection.GAUGES)})")
    if cfg.model.init_spacing not in INIT_SPACINGS:
        named = ", ".join(str(k) for k in INIT_SPACINGS if k is not None)
        raise InputError("model.init_spacing", f"unknown rule '{cfg.model.init_spacing}' (choose from {named},"
                         " or null)")
    if cfg.backend not in BACKENDS:
        raise InputError("backend", f"unknown backend '{cfg.backend}' (choose from {', '.join(BACKENDS)})")


def train(cfg: TrainConfig, scene: Scene, tracker: Tracker | None = None) -> RunResult:
    """Train one run and evaluate it; never raises for divergence (returns FAILED instead).

    Bad input (unknown policy, unavailable feature, bad scene) raises ``InputError``.
    """
    tracker = tracker or NullTracker()
    check_config(cfg)
    if needs_child(cfg):  # another determinism environment / kernel dispatch: train in a fresh process
        return train_in_child(cfg, tracker)
    out_dir = Path(cfg.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    save_config(cfg, out_dir)
    env = enter(cfg)
    (out_dir / "determinism.json").write_text(json.dumps(env.domain, indent=2))
    tracker.set_tags({f"determinism.{k}": v for k, v in env.domain.items()})
    torch.manual_seed(cfg.seed)

    clock = time.perf_counter()
    state = TrainState.create(cfg, scene, env.device)
    if state.init_stats:  # what the initial point set is made of (ftgspp/init/quality.py)
        (out_dir / "init.json").write_text(json.dumps(state.init_stats, indent=1, sort_keys=True))
    lpips_net = _lpips_loss_net(cfg, env.device)
    init_seconds = time.perf_counter() - clock
    ckpt = out_dir / CHECKPOINT
    if cfg.resume and ckpt.exists() and state.load(ckpt):
        log.info("resumed from %s at iteration %d", ckpt, state.step)
    tracker.log_params({"n_gaussians_init": len(state.model), "scene_extent": state.extent})

    try:
        _loop(cfg, scene, state, tracker, out_dir, lpips_net)
    except Diverged as exc:
        log.warning("diverged: %s", exc)
        return RunResult(status="FAILED", failure="diverged", out_dir=out_dir,
                         metrics={"train_seconds": exc.seconds, "diverged_at": float(exc.step)})

    model, cc, elapsed = state.model, state.cc, state.elapsed
    # Order matters: the model, then the network-free metrics, are on disk before any
    # optional metric (LPIPS) or diagnostic runs, so none of those can lose the run.
    save_model(model, cc, out_dir)
    clock = time.perf_counter()
    renders = HeldOutRenders(model, scene, cfg)  # each held-out view rendered once, for all three
    metrics, artifacts = evaluate(model, scene, cfg, out_dir, renders=renders)
    metrics.update({
        "init_seconds": init_seconds,  # where a run's time goes besides training (benchmarks/runs_per_hour.py)
        "eval_seconds": time.perf_counter() - clock,
        "train_seconds": elapsed,
        "iters_per_second": cfg.iterations / elapsed if elapsed > 0 else float("nan"),
        "peak_rss_mb": _peak_rss_mb(),
        "n_gaussians": float(len(model)),
        "relocated_total": float(state.relocated),
        **state.init_stats,  # what the initial point set is made of (also in init.json)
        # Gaussians drawn nowhere in the clip: their opacity there never exceeds the relocation threshold
        "n_faded": float((model.peak_opacity(*clip_window(scene)) <= cfg.strategy.min_opacity).sum()),
    })
    _write_metrics(out_dir, metrics)
    clock = time.perf_counter()
    metrics.update(evaluate_lpips(model, scene, cfg, renders=renders))
    metrics["eval_lpips_seconds"] = time.perf_counter() - clock
    _write_metrics(out_dir, metrics)
    diag_files: list[Path] = []
    if cfg.diagnostics:  # lifetime / velocity / x-t / motion-error plots and the numbers studies tabulate
        clock = time.perf_counter()
        diag = run_diagnostics(model, scene, cfg, out_dir / "diagnostics", figures=cfg.diagnostics_figures,
                               renders=renders)
        metrics.update(diag.metrics())
        metrics["diagnostics_seconds"] = time.perf_counter() - clock
        diag_files = list(diag.files.values())
    del renders  # up to 256 MB of renders
    metrics["peak_rss_mb"] = _peak_rss_mb()  # now including evaluation and diagnostics
    _write_metrics(out_dir, metrics)
    tracker.log_metrics(metrics)
    for a in artifacts:
        tracker.log_artifact(a, "renders")
    for a in diag_files:
        tracker.log_artifact(a, "diagnostics")
    return RunResult(status="FINISHED", metrics=metrics, out_dir=out_dir, artifacts=artifacts)


def _write_metrics(out_dir: Path, metrics: dict[str, float]) -> None:
    (out_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))


def _lpips_loss_net(cfg: TrainConfig, device: torch.device) -> torch.nn.Module | None:
    """LPIPS-Alex for the optional perceptual loss term (GPU profiles); None when its weight is 0."""
    if cfg.loss.lpips <= 0:
        return None
    from ftgspp.lpips import load_lpips

    return load_lpips("alex", device=device)  # missing weights: one-line InputError naming the fix


def clip_window(scene: Scene) -> tuple[float, float]:
    """The times the training frames span (seconds): where a Gaussian can be drawn."""
    return float(scene.times[0]), float(scene.times[-1])


def _loop(cfg: TrainConfig, scene: Scene, st: TrainState, tracker: Tracker, out_dir: Path,
          lpips_net: torch.nn.Module | None) -> None:
    """The optimisation loop from iteration ``st.step`` to ``cfg.iterations``."""
    device = st.model.params["means"].device
    background = torch.tensor(cfg.background, dtype=torch.float32, device=device)
    train_slot = {cam: i for i, cam in enumerate(scene.train_ids)}
    start = st.step
    if start >= cfg.iterations:
        log.info("run already complete; evaluation only")
    bar = tqdm(range(start, cfg.iterations), initial=start, total=cfg.iterations, disable=not cfg.progress,
               desc="train", unit="it", dynamic_ncols=True, mininterval=1.0)
    fast_adam = plain_fused_adam(st.optimizer)  # optimizer.step()'s bits with less Python (ftgspp.optim)
    window = clip_window(scene)
    t_session = time.perf_counter()
    t0 = t_session - st.elapsed  # the clock counts training seconds across resumes
    for it in bar:
        step = it + 1
        cam_idx, frame = st.sampler.next()
        gt = torch.from_numpy(scene.image(cam_idx, frame)).to(device)
        bg = torch.rand(3, device=device) if cfg.random_background else background
        out, g = render_view(st.model, scene.cameras[cam_idx], float(scene.times[frame]), sh_degree_at(cfg, it),
                             background=bg, backend=cfg.backend)
        if it == start:  # which path rendered (a method's fused cpu stage or the generic one): its bits differ
            tracker.log_params({"render_stage": out.stage})
        use_cc = st.cc is not None and step > cc_start(cfg)
        image = st.cc(out.image, train_slot[cam_idx]) if use_cc else out.image
        terms = loss_terms(cfg, st.model, g, image, gt, st.cc if use_cc else None, lpips_net)
        loss = terms["total"]
        if not torch.isfinite(loss):
            raise Diverged(step, time.perf_counter() - t0, loss.item())
        loss.backward()

        if out.means2d.grad is not None:
            st.relocator.accumulate(st.reloc_stats, out.means2d.grad, out.radii)
        set_learning_rates(st.optimizer, it, cfg)
        if fast_adam:
            adam_step(st.optimizer)
        else:
            st.optimizer.step()
        clear_grads(st.optimizer)
        if st.relocator.due(step):
            clip = st.model.peak_opacity(*window) if cfg.strategy.dead == "clip_opacity" else None
            moved = st.relocator.step(st.model.params, st.optimizer, st.reloc_stats, st.reloc_gen, clip)
            st.relocated += int(moved)
            tracker.log_metrics({"relocated": float(moved)}, step=step)
        st.step, st.elapsed = step, time.perf_counter() - t0

        if step % cfg.log_every == 0 or step == cfg.iterations:
            l1, mse = logged_photometric(image, gt)  # the same bits for any thread count
            psnr = -10.0 * math.log10(max(mse, 1e-12))
            rate = (step - start) / max(time.perf_counter() - t_session, 1e-9)
            bar.set_postfix(loss=f"{loss.item():.4f}", psnr=f"{psnr:.2f}", its=f"{rate:.1f}")
            logged = {"loss": loss.item(), "l1": l1, "train_psnr": psnr}
            if st.cc is not None:  # a colour-gauge drift shows here before the held-out PSNR drops
                logged["cc_mean_delta"], logged["cc_mean_bias"] = st.cc.mean_transform()
            tracker.log_metrics(logged, step=step)
        if step % cfg.checkpoint_every == 0 and step < cfg.iterations:
            st.save(out_dir / CHECKPOINT)
    bar.close()
    st.elapsed = time.perf_counter() - t0
    st.save(out_dir / CHECKPOINT)


if __name__ == "__main__":  # a child started by ftgspp.runtime.child.train_in_child
    import sys

    from ftgspp.runtime.child import child_main

    raise SystemExit(child_main(Path(sys.argv[1]), train))
