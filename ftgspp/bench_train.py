"""``ftgspp bench train`` and ``ftgspp bench scale``: whole training iterations, timed.

``bench train`` times what ``ftgspp.trainer.train`` does per step — evaluate the Gaussians
at the frame's time, project, render, loss (L1 + SSIM + regularisers), backward, Adam, and
relocation every 100 iterations (amortised) — for every backend, on the same small
synthetic scene from the same seed. Backends alternate between repeats; the figure is the
median of the trainer's own loop clock (``train_seconds``), so initialisation and
evaluation are not counted. ``reference`` (pure PyTorch autograd everywhere, the
correctness oracle) is the slow path the ``cpu`` backend is compared with in the same run.
``--breakdown`` adds one more run per backend under ``PhaseTimer`` (``bench_phases.py``):
milliseconds per phase of an iteration.

``bench scale`` sweeps Gaussian counts × resolutions, each point in a fresh process so
its peak RSS is its own, and fits how the cost grows: ms ≈ a · N^b · P^c (N Gaussians,
P pixels), with a log–log plot.

    ftgspp bench train [--iterations 200] [--budget 5000] [--repeats 2] [--breakdown] [--json]
    ftgspp bench scale [--counts 1000,5000,20000,100000] [--sizes 128x96,256x192,512x384]
                       [--iterations 30] [--plot benchmarks/cost_curve.png] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
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


def bench_config(out_dir: Path, scene_dir: Path, backend: str, iterations: int, budget: int, seed: int) -> TrainConfig:
    """The benchmark's run: relocation every 100 iterations from the start, no diagnostics."""
    cfg = TrainConfig(iterations=iterations, budget=budget, backend=backend, seed=seed, progress=False,
                      diagnostics=False, resume=False, out_dir=str(out_dir), checkpoint_every=10**9)
    cfg.data.path = str(scene_dir)
    cfg.init.keyframe_stride = 5
    cfg.strategy.refine_start_iter = 0
    cfg.strategy.refine_stop_iter = iterations + 1
    return cfg


def _scene(root: Path, width: int, height: int, seed: int) -> Path:
    return generate(root / f"scene_{width}x{height}", preset="studio", seed=seed, width=width, height=height,
                    n_frames=10, n_cameras=8)


def bench_train(
    iterations: int = 200, budget: int = 5000, repeats: int = 2, width: int = 128, height: int = 96,
    backends: list[str] | None = None, seed: int = 0, breakdown: bool = False,
) -> dict[str, Any]:
    """Median milliseconds per training iteration for each backend (and ratios to ``reference``).

    With ``breakdown``, ``result["breakdown"][backend]`` maps phase -> ms per iteration.
    """
    from ftgspp.bench_phases import PhaseTimer
    from ftgspp.trainer import train

    backends = backends or train_backends()
    with tempfile.TemporaryDirectory(prefix="ftgspp-bench-") as tmp:
        root = Path(tmp)
        scene_dir = _scene(root, width, height, seed)
        scene = load_scene(DataConfig(path=str(scene_dir)))
        per_it: dict[str, list[float]] = {b: [] for b in backends}
        for b in backends:  # warm-up: Numba compiles (or loads its cache) on first use
            train(bench_config(root / f"{b}_warmup", scene_dir, b, 3, budget, seed), scene)
        for r in range(repeats):
            for b in backends:
                result = train(bench_config(root / f"{b}_{r}", scene_dir, b, iterations, budget, seed), scene)
                per_it[b].append(1000.0 * result.metrics["train_seconds"] / iterations)
        phases: dict[str, dict[str, float]] = {}
        if breakdown:
            for b in backends:
                with PhaseTimer() as timer:
                    train(bench_config(root / f"{b}_phases", scene_dir, b, iterations, budget, seed), scene)
                phases[b] = timer.per_iteration(iterations)
    ms = {b: statistics.median(v) for b, v in per_it.items()}
    ref = ms.get("reference")
    out = {
        "iterations": iterations, "budget": budget, "width": width, "height": height, "repeats": repeats,
        "threads": _threads(),
        "backends": {b: {"ms_per_iter": ms[b], "iters_per_second": 1000.0 / ms[b], "all_ms": per_it[b]}
                     for b in backends},
        "speedup_vs_reference": {b: ref / ms[b] for b in backends} if ref else {},
    }
    if breakdown:
        out["breakdown"] = phases
    return out


def _threads() -> int:
    import torch

    return torch.get_num_threads()


def format_train_table(result: dict[str, Any]) -> str:
    """A small text table of ``bench_train`` output (plus the per-phase breakdown if present)."""
    lines = [f"training iteration, {result['budget']} Gaussians, {result['width']}x{result['height']}, "
             f"{result['iterations']} iterations x {result['repeats']} repeats (median), "
             f"{result.get('threads', '?')} threads",
             f"{'backend':<10} {'ms/iter':>9} {'it/s':>8} {'vs reference':>13}"]
    for b, r in result["backends"].items():
        sp = result["speedup_vs_reference"].get(b)
        lines.append(f"{b:<10} {r['ms_per_iter']:>9.2f} {r['iters_per_second']:>8.1f} "
                     f"{(f'{sp:.1f}x' if sp else '-'):>13}")
    if result.get("breakdown"):
        lines += ["", format_breakdown(result["breakdown"])]
    return "\n".join(lines)


def format_breakdown(breakdown: dict[str, dict[str, float]]) -> str:
    """Phases as rows, backends as columns, ms per iteration (instrumented run)."""
    names = list(breakdown)
    phases: list[str] = []
    for b in names:
        phases += [p for p in breakdown[b] if p not in phases]
    width = max(len(p) for p in phases) + 2
    lines = ["per-phase ms per iteration (one instrumented run per backend)",
             f"{'phase':<{width}}" + "".join(f"{b:>12}" for b in names)]
    for p in phases:
        lines.append(f"{p:<{width}}" + "".join(
            f"{breakdown[b][p]:>12.2f}" if p in breakdown[b] else f"{'-':>12}" for b in names))
    lines.append(f"{'total':<{width}}" + "".join(f"{sum(breakdown[b].values()):>12.2f}" for b in names))
    return "\n".join(lines)


# ------------------------------------------------------------------------------ scale


def _one_point(width: int, height: int, budget: int, iterations: int, backend: str, scene_root: str,
               seed: int = 0) -> dict[str, Any]:
    """One sweep point in this process: ms per iteration, per phase, and this process's peak RSS."""
    import resource

    from ftgspp.bench_phases import PhaseTimer
    from ftgspp.trainer import train

    root = Path(scene_root)
    scene_dir = root / f"scene_{width}x{height}"
    if not scene_dir.exists():
        _scene(root, width, height, seed)
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
                echo=print) -> dict[str, Any]:
    """Sweep ``counts`` × ``sizes``, each point in a fresh Python process."""
    points = []
    with tempfile.TemporaryDirectory(prefix="ftgspp-scale-scenes-") as scenes:
        for width, height in sizes:
            for n in counts:
                args = json.dumps([width, height, n, iterations, backend, scenes])
                proc = subprocess.run([sys.executable, "-m", "ftgspp.bench_train", "--one-point", args],
                                      capture_output=True, text=True)
                if proc.returncode != 0:
                    raise RuntimeError(f"sweep point {n} Gaussians {width}x{height} failed: "
                                       f"{(proc.stderr.strip().splitlines() or ['?'])[-1]}")
                point = json.loads(proc.stdout.strip().splitlines()[-1])
                echo(f"[scale] {n:>7} Gaussians {width}x{height}: {point['ms_per_iter']:8.2f} ms/iter, "
                     f"peak RSS {point['peak_rss_mb']:.0f} MB")
                points.append(point)
    return {"backend": backend, "iterations": iterations, "threads": _threads(), "points": points,
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


# -------------------------------------------------------------------------------- cli


def add_parsers(sub: argparse._SubParsersAction) -> None:
    """The ``train`` and ``scale`` subcommands of ``ftgspp bench``."""
    train = sub.add_parser("train", help="whole training iterations of every backend (ftgspp/bench_train.py)")
    train.add_argument("--iterations", type=int, default=200)
    train.add_argument("--budget", type=int, default=5000, help="number of Gaussians")
    train.add_argument("--repeats", type=int, default=2)
    train.add_argument("--width", type=int, default=128)
    train.add_argument("--height", type=int, default=96)
    train.add_argument("--backends", default="", help="comma-separated (default: every available one)")
    train.add_argument("--breakdown", action="store_true", help="also time every phase of an iteration")
    train.add_argument("--json", action="store_true", help="print one JSON line instead of a table")
    scale = sub.add_parser("scale", help="cost of an iteration over Gaussian counts x resolutions")
    scale.add_argument("--counts", default="1000,5000,20000,100000")
    scale.add_argument("--sizes", default="128x96,256x192,512x384")
    scale.add_argument("--iterations", type=int, default=30)
    scale.add_argument("--backend", default="cpu")
    scale.add_argument("--plot", type=Path, default=Path("benchmarks/cost_curve.png"))
    scale.add_argument("--json", action="store_true", help="print one JSON line instead of a table")


def _sizes(text: str) -> list[tuple[int, int]]:
    try:
        return [(int(w), int(h)) for w, h in (s.lower().split("x") for s in text.split(","))]
    except ValueError:
        from ftgspp.errors import InputError

        raise InputError("--sizes", f"expected WxH[,WxH...], got {text!r}") from None


def run(args: argparse.Namespace) -> int:
    """Dispatch ``bench train`` / ``bench scale``; returns the exit status."""
    if args.command == "train":
        result = bench_train(iterations=args.iterations, budget=args.budget, repeats=args.repeats,
                             width=args.width, height=args.height, breakdown=args.breakdown,
                             backends=[b for b in args.backends.split(",") if b] or None)
        print(json.dumps(result) if args.json else format_train_table(result))
        return 0
    counts = [int(c) for c in args.counts.split(",")]
    result = bench_scale(counts, _sizes(args.sizes), args.iterations, args.backend,
                         echo=(lambda s: print(s, file=sys.stderr)) if args.json else print)
    result["plot"] = str(plot_scale(result, args.plot))
    print(json.dumps(result) if args.json else format_scale_table(result) + f"\nplot: {result['plot']}")
    return 0


if __name__ == "__main__":  # one sweep point in a fresh process (bench_scale)
    if sys.argv[1:2] == ["--one-point"]:
        print(json.dumps(_one_point(*json.loads(sys.argv[2]))))
