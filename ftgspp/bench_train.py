"""``ftgspp bench train``: time whole training iterations of every backend, in one process.

A training iteration here is exactly what ``ftgspp.trainer.train`` does per step: evaluate
the Gaussians at the frame's time, project, render, loss (L1 + SSIM + regularisers),
backward, Adam steps, and relocation every 100 iterations (amortised). Each backend trains
the same small synthetic scene from the same seed; backends alternate between repeats and
the figure is the median of the trainer's own loop clock (``train_seconds``), so
initialisation and evaluation are not counted.

    ftgspp bench train [--iterations 200] [--budget 5000] [--repeats 2] [--json]
"""

from __future__ import annotations

import statistics
import tempfile
from pathlib import Path
from typing import Any

from ftgspp.config import DataConfig, TrainConfig
from ftgspp.data.load import load_scene
from ftgspp.data.synthetic import generate
from ftgspp.render import BACKENDS, resolve_backend


def train_backends() -> list[str]:
    """Backends that can train on this machine (gsplat only with CUDA)."""
    import torch

    names = ["reference"]
    if resolve_backend("auto", torch.device("cpu")) == "cpu":
        names.append("cpu")
    if torch.cuda.is_available() and resolve_backend("auto", torch.device("cuda")) == "gsplat":
        names.append("gsplat")
    return [n for n in names if n in BACKENDS]


def bench_train(
    iterations: int = 200, budget: int = 5000, repeats: int = 2, width: int = 128, height: int = 96,
    backends: list[str] | None = None, seed: int = 0,
) -> dict[str, Any]:
    """Median milliseconds per training iteration for each backend (and ratios to ``reference``)."""
    from ftgspp.trainer import train

    backends = backends or train_backends()
    with tempfile.TemporaryDirectory(prefix="ftgspp-bench-") as tmp:
        root = Path(tmp)
        scene_dir = generate(root / "scene", preset="studio", seed=seed, width=width, height=height,
                             n_frames=10, n_cameras=8)
        scene = load_scene(DataConfig(path=str(scene_dir)))
        per_it: dict[str, list[float]] = {b: [] for b in backends}
        for r in range(repeats):
            for b in backends:
                cfg = TrainConfig(iterations=iterations, budget=budget, backend=b, seed=seed, progress=False,
                                  diagnostics=False, resume=False, out_dir=str(root / f"{b}_{r}"))
                cfg.init.keyframe_stride = 5
                cfg.strategy.refine_start_iter = 0
                cfg.strategy.refine_stop_iter = iterations + 1
                result = train(cfg, scene)
                per_it[b].append(1000.0 * result.metrics["train_seconds"] / iterations)
    ms = {b: statistics.median(v) for b, v in per_it.items()}
    ref = ms.get("reference")
    return {
        "iterations": iterations, "budget": budget, "width": width, "height": height, "repeats": repeats,
        "backends": {b: {"ms_per_iter": ms[b], "iters_per_second": 1000.0 / ms[b], "all_ms": per_it[b]}
                     for b in backends},
        "speedup_vs_reference": {b: ref / ms[b] for b in backends} if ref else {},
    }


def format_train_table(result: dict[str, Any]) -> str:
    """A small text table of ``bench_train`` output."""
    lines = [f"training iteration, {result['budget']} Gaussians, {result['width']}x{result['height']}, "
             f"{result['iterations']} iterations x {result['repeats']} repeats (median)",
             f"{'backend':<10} {'ms/iter':>9} {'it/s':>8} {'vs reference':>13}"]
    for b, r in result["backends"].items():
        sp = result["speedup_vs_reference"].get(b)
        lines.append(f"{b:<10} {r['ms_per_iter']:>9.2f} {r['iters_per_second']:>8.1f} "
                     f"{(f'{sp:.1f}x' if sp else '-'):>13}")
    return "\n".join(lines)
