"""``ftgspp bench scale``: the cost of a training iteration over Gaussian counts × resolutions.

Every point runs in a fresh process (``python -m ftgspp.bench.scale --one-point``), so its
peak RSS is its own: a warm-up, a timed run and a run under ``PhaseTimer``. The sweep fits
how the cost grows, ms ≈ a · N^b · P^c (N Gaussians, P pixels), and draws a log–log plot.

    ftgspp bench scale [--counts 1000,5000,20000,100000] [--sizes 128x96,256x192,512x384]
                       [--iterations 30] [--plot benchmarks/cost_curve.png] [--json]
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable

import torch

from ftgspp.bench.phases import PhaseTimer
from ftgspp.bench.train_speed import bench_config, bench_scene
from ftgspp.config import DataConfig
from ftgspp.data.load import load_scene


def _one_point(width: int, height: int, budget: int, iterations: int, backend: str, scene_root: str,
               seed: int = 0) -> dict[str, Any]:
    """One sweep point in this process: ms per iteration, per phase, and this process's peak RSS."""
    import resource

    from ftgspp.trainer import train

    root = Path(scene_root)
    scene_dir = root / f"scene_{width}x{height}"
    if not scene_dir.exists():
        bench_scene(root, width, height, seed)
    scene = load_scene(DataConfig(path=str(scene_dir)))
    with tempfile.TemporaryDirectory(prefix="ftgspp-scale-") as tmp:
        train(bench_config(Path(tmp) / "warmup", scene_dir, backend, 3, budget, seed), scene)
        plain = train(bench_config(Path(tmp) / "plain", scene_dir, backend, iterations, budget, seed), scene)
        with PhaseTimer() as timer:
            train(bench_config(Path(tmp) / "phases", scene_dir, backend, iterations, budget, seed), scene)
    return {"n": budget, "width": width, "height": height, "pixels": width * height,
            "ms_per_iter": 1000.0 * plain.metrics["train_seconds"] / iterations,
            "phases": timer.per_iteration(iterations),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def fit_exponents(points: list[dict[str, Any]]) -> dict[str, float]:
    """Least squares of log ms = log a + b log N + c log P over the sweep points."""
    import numpy as np

    X = np.array([[1.0, np.log(p["n"]), np.log(p["pixels"])] for p in points])
    y = np.log([p["ms_per_iter"] for p in points])
    (log_a, b, c), *_ = np.linalg.lstsq(X, y, rcond=None)
    residual = y - X @ np.array([log_a, b, c])
    return {"a_ms": float(np.exp(log_a)), "exponent_n": float(b), "exponent_pixels": float(c),
            "rms_log_residual": float(np.sqrt(np.mean(residual**2)))}


def bench_scale(counts: list[int], sizes: list[tuple[int, int]], iterations: int = 30, backend: str = "cpu",
                echo: Callable[[str], None] = print) -> dict[str, Any]:
    """Sweep ``counts`` × ``sizes``, each point in a fresh Python process."""
    points = []
    with tempfile.TemporaryDirectory(prefix="ftgspp-scale-scenes-") as scenes:
        for width, height in sizes:
            for n in counts:
                args = json.dumps([width, height, n, iterations, backend, scenes])
                proc = subprocess.run([sys.executable, "-m", "ftgspp.bench.scale", "--one-point", args],
                                      capture_output=True, text=True)
                if proc.returncode != 0:
                    raise RuntimeError(f"sweep point {n} Gaussians {width}x{height} failed: "
                                       f"{(proc.stderr.strip().splitlines() or ['?'])[-1]}")
                point = json.loads(proc.stdout.strip().splitlines()[-1])
                echo(f"[scale] {n:>7} Gaussians {width}x{height}: {point['ms_per_iter']:8.2f} ms/iter, "
                     f"peak RSS {point['peak_rss_mb']:.0f} MB")
                points.append(point)
    return {"backend": backend, "iterations": iterations, "threads": torch.get_num_threads(), "points": points,
            "fit": fit_exponents(points)}


def plot_scale(result: dict[str, Any], path: Path) -> Path:
    """Log–log plot of ms per iteration against Gaussian count, one line per resolution."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    by_size: dict[str, list[dict]] = {}
    for p in result["points"]:
        by_size.setdefault(f"{p['width']}x{p['height']}", []).append(p)
    for label, pts in by_size.items():
        pts = sorted(pts, key=lambda p: p["n"])
        axes[0].loglog([p["n"] for p in pts], [p["ms_per_iter"] for p in pts], "o-", label=label)
        axes[1].loglog([p["n"] for p in pts], [p["peak_rss_mb"] for p in pts], "o-", label=label)
    fit = result["fit"]
    axes[0].set_title(f"ms per iteration ≈ {fit['a_ms']:.2g}·N^{fit['exponent_n']:.2f}·P^{fit['exponent_pixels']:.2f}")
    axes[0].set_xlabel("Gaussians N")
    axes[0].set_ylabel("ms per training iteration")
    axes[1].set_title("peak RSS of the process")
    axes[1].set_xlabel("Gaussians N")
    axes[1].set_ylabel("MB")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(title="resolution")
    fig.suptitle(f"cost of a training iteration, {result['backend']} backend, {result['threads']} threads")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def format_scale_table(result: dict[str, Any]) -> str:
    """Points as rows (ms, biggest phases, RSS) and the fitted exponents."""
    lines = [f"{'N':>8} {'size':>9} {'ms/iter':>9} {'RSS MB':>8}  biggest phases (ms)"]
    for p in result["points"]:
        top = sorted(p["phases"].items(), key=lambda kv: -kv[1])[:3]
        lines.append(f"{p['n']:>8} {p['width']}x{p['height']:<5} {p['ms_per_iter']:>9.2f} {p['peak_rss_mb']:>8.0f}  "
                     + ", ".join(f"{k} {v:.1f}" for k, v in top))
    f = result["fit"]
    lines.append(f"fit: ms ≈ {f['a_ms']:.3g} · N^{f['exponent_n']:.3f} · P^{f['exponent_pixels']:.3f} "
                 f"(rms log residual {f['rms_log_residual']:.3f})")
    return "\n".join(lines)


if __name__ == "__main__":  # one sweep point in a fresh process (bench_scale)
    if sys.argv[1:2] == ["--one-point"]:
        print(json.dumps(_one_point(*json.loads(sys.argv[2]))))
