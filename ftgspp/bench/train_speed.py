"""``ftgspp bench train``: whole training iterations of every backend, timed.

It times what ``ftgspp.trainer.train`` does per step — evaluate the Gaussians at the
frame's time, project, render, loss (L1 + SSIM + regularisers), backward, Adam, and
relocation every 100 iterations (amortised) — for every backend, on the same small
synthetic scene from the same seed. Backends alternate between repeats; the figure is the
median of the trainer's own loop clock (``train_seconds``), so initialisation and
evaluation are not counted. ``reference`` (pure PyTorch autograd everywhere, the
correctness oracle) is the slow path the ``cpu`` backend is compared with in the same run.
``--breakdown`` adds one more run per backend under ``PhaseTimer`` (``phases.py``):
milliseconds per phase of an iteration. ``--models ftgs,stg`` times each method
(``conf/model/<name>.yaml``) on each backend, alternating, and gives each method's time over
the first's (``ratio_vs_first_model``): what a method costs against another, measured in one run.

By default the timed iterations are the first ones from initialisation. ``--after N`` times
iterations N+1 .. N+``--iterations`` instead: each row trains its first N iterations once,
untimed (a run of N iterations, so its learning-rate schedule ends at N), and every repeat
resumes a copy of that checkpoint; the figure is the loop clock of the resumed part alone. A
method whose Gaussians start large (STGS from the public code's spacing) costs more at the start
than later, and this reads the later cost in the same run as the first one's.

    ftgspp bench train [--iterations 200] [--budget 5000] [--repeats 2] [--breakdown] [--json]
    ftgspp bench train --models ftgs,stg --backends cpu [--after 1000]
"""

from __future__ import annotations

import shutil
import statistics
import tempfile
from pathlib import Path
from typing import Any

import torch

from ftgspp.bench.isa import describe, host_isa
from ftgspp.bench.phases import PhaseTimer
from ftgspp.bench.timing import usable_backends
from ftgspp.config import DataConfig, ModelConfig, TrainConfig
from ftgspp.data.load import load_scene
from ftgspp.data.synthetic.build import generate

CONF_MODELS = Path(__file__).resolve().parents[2] / "conf" / "model"


def model_config(name: str) -> ModelConfig:
    """The ``ModelConfig`` of ``conf/model/<name>.yaml`` (``model=<name>`` on the command line)."""
    import yaml

    path = CONF_MODELS / f"{name}.yaml"
    if not path.is_file():
        from ftgspp.errors import InputError

        raise InputError("--models", f"no model '{name}' (conf/model/ has {', '.join(sorted(p.stem for p in CONF_MODELS.glob('*.yaml')))})")
    return ModelConfig(**(yaml.safe_load(path.read_text()) or {}))


def bench_config(out_dir: Path, scene_dir: Path, backend: str, iterations: int, budget: int, seed: int,
                 model: str = "ftgs", refine_until: int | None = None) -> TrainConfig:
    """The benchmark's run: relocation every 100 iterations from the start (until ``refine_until``,
    default the last iteration), no diagnostics."""
    cfg = TrainConfig(iterations=iterations, budget=budget, backend=backend, seed=seed, progress=False,
                      diagnostics=False, resume=False, out_dir=str(out_dir), checkpoint_every=10**9,
                      model=model_config(model))
    cfg.data.path = str(scene_dir)
    cfg.init.keyframe_stride = 5
    cfg.strategy.refine_start_iter = 0
    cfg.strategy.refine_stop_iter = (refine_until or iterations) + 1
    return cfg


def bench_scene(root: Path, width: int, height: int, seed: int) -> Path:
    """The benchmark's synthetic studio scene (8 cameras, 10 frames) under ``root``; returns its folder."""
    return generate(root / f"scene_{width}x{height}", preset="studio", seed=seed, width=width, height=height,
                    n_frames=10, n_cameras=8)


def bench_train(
    iterations: int = 200, budget: int = 5000, repeats: int = 2, width: int = 128, height: int = 96,
    backends: list[str] | None = None, seed: int = 0, breakdown: bool = False, models: list[str] | None = None,
    after: int = 0,
) -> dict[str, Any]:
    """Median milliseconds per training iteration for each backend (and ratios to ``reference``).

    ``after`` > 0 times iterations ``after`` + 1 .. ``after`` + ``iterations`` (module docstring).

    With several ``models`` the rows are ``<model>/<backend>`` and ``ratio_vs_first_model`` gives
    each row's time over the first model's on the same backend. With ``breakdown``,
    ``result["breakdown"][row]`` maps phase -> ms per iteration.
    """
    from ftgspp.trainer import train

    backends = backends or usable_backends()
    models = models or ["ftgs"]
    key = lambda m, b: b if len(models) == 1 else f"{m}/{b}"  # noqa: E731
    rows = [(m, b, key(m, b)) for m in models for b in backends]
    with tempfile.TemporaryDirectory(prefix="ftgspp-bench-") as tmp:
        root = Path(tmp)
        scene_dir = bench_scene(root, width, height, seed)
        scene = load_scene(DataConfig(path=str(scene_dir)))
        prefix_seconds: dict[tuple[str, str], float] = {}

        def run(m: str, b: str, tag: Any, its: int) -> float:
            """Train ``its`` timed iterations (after the row's untimed prefix); their loop seconds."""
            out = root / f"{m}_{b}_{tag}"
            if not after:
                return train(bench_config(out, scene_dir, b, its, budget, seed, m), scene).metrics["train_seconds"]
            prefix = root / f"{m}_{b}_prefix"
            if (m, b) not in prefix_seconds:
                cfg = bench_config(prefix, scene_dir, b, after, budget, seed, m, refine_until=after + iterations)
                prefix_seconds[m, b] = train(cfg, scene).metrics["train_seconds"]
            shutil.copytree(prefix, out)
            cfg = bench_config(out, scene_dir, b, after + its, budget, seed, m, refine_until=after + iterations)
            cfg.resume = True  # from the prefix's checkpoint: its loop clock goes on from the prefix's
            return train(cfg, scene).metrics["train_seconds"] - prefix_seconds[m, b]

        per_it: dict[str, list[float]] = {key: [] for _, _, key in rows}
        for m, b, _k in rows:  # warm-up: Numba compiles (or loads its cache) on first use
            run(m, b, "warmup", 3)
        for r in range(repeats):
            for m, b, k in rows:
                per_it[k].append(1000.0 * run(m, b, r, iterations) / iterations)
        phases: dict[str, dict[str, float]] = {}
        work: dict[str, dict[str, float]] = {}
        if breakdown:
            for m, b, k in rows:
                with PhaseTimer() as timer:
                    run(m, b, "phases", iterations)
                phases[k] = timer.per_iteration(iterations)
                if counted := timer.work_per_view():
                    work[k] = counted
    ms = {k: statistics.median(v) for k, v in per_it.items()}
    out = {
        "iterations": iterations, "after": after, "budget": budget, "width": width, "height": height,
        "repeats": repeats,
        "threads": torch.get_num_threads(), "isa": host_isa(), "models": models,
        "backends": {k: {"ms_per_iter": ms[k], "iters_per_second": 1000.0 / ms[k], "all_ms": per_it[k]} for k in ms},
        "speedup_vs_reference": {k: ms[key(m, "reference")] / ms[k] for m, b, k in rows if key(m, "reference") in ms},
    }
    if len(models) > 1:
        out["ratio_vs_first_model"] = {k: ms[k] / ms[key(models[0], b)] for m, b, k in rows}
    if breakdown:
        out["breakdown"] = phases
        out["work"] = work
    return out


def format_train_table(result: dict[str, Any]) -> str:
    """A small text table of ``bench_train`` output (plus the per-phase breakdown if present)."""
    lines = [f"training iteration, {result['budget']} Gaussians, {result['width']}x{result['height']}, "
             f"{result['iterations']} iterations"
             + (f" after the first {result['after']}" if result.get("after") else "")
             + f" x {result['repeats']} repeats (median), "
             f"{result.get('threads', '?')} threads",
             *([describe(result["isa"])] if "isa" in result else []),
             f"{'backend':<14} {'ms/iter':>9} {'it/s':>8} {'vs reference':>13}"
             + (f" {'vs ' + result['models'][0]:>10}" if "ratio_vs_first_model" in result else "")]
    for b, r in result["backends"].items():
        sp = result["speedup_vs_reference"].get(b)
        vs_first = result.get("ratio_vs_first_model", {}).get(b)
        lines.append(f"{b:<14} {r['ms_per_iter']:>9.2f} {r['iters_per_second']:>8.1f} "
                     f"{(f'{sp:.1f}x' if sp else '-'):>13}" + (f" {vs_first:>9.2f}x" if vs_first else ""))
    if result.get("breakdown"):
        lines += ["", format_breakdown(result["breakdown"])]
    if result.get("work"):
        lines += ["", format_work(result["work"])]
    return "\n".join(lines)


def format_work(work: dict[str, dict[str, float]]) -> str:
    """The cpu rasterizer's work per rendered view (``PhaseTimer.work_per_view``), rows as columns."""
    names = list(work)
    lines = ["cpu rasterizer work per rendered view (same instrumented run)",
             f"{'':<30}" + "".join(f"{b:>12}" for b in names)]
    for key in next(iter(work.values())):
        lines.append(f"{key:<30}" + "".join(f"{work[b].get(key, float('nan')):>12.2f}" for b in names))
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
