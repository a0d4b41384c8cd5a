"""Two GPU measurements of ``ftgspp check-gpu`` that ``ftgspp bench`` cannot make as it is:

- ``render_speed``: one rasterization, forward and forward + backward, of ``ftgspp bench render``'s
  random scene at a size where the ``reference`` backend and the dense yardstick are out of
  reach (500k Gaussians at paper resolution): gsplat with its inputs on the GPU, and the
  ``cpu`` backend, timed alike (``ftgspp.bench.timing.time_backend``, medians), and their ratio;
- ``timed_training``: one training run of a composed config (the paper profile) stopped at a
  wall-clock deadline: iterations per second from the trainer's own progress log, initialisation
  seconds and peak GPU memory. The trainer is unchanged; ``DeadlineTracker``, a ``Tracker``,
  sees each logged step and ends the run once the deadline has passed.

    python -m harness.run.gpu_speed render --n 500000 --width 1352 --height 1014
    python -m harness.run.gpu_speed train --seconds 120 --out DIR profile=paper data.path=SCENE backend=gsplat

Each prints one JSON line.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import torch


class DeadlineReached(Exception):
    """Raised by ``DeadlineTracker`` from inside the training loop once its deadline has passed."""


class DeadlineTracker:
    """A ``Tracker`` that records when each logged step happened and stops the run at ``deadline``
    (``time.time()`` seconds). ``log_params`` is the trainer's last call before its loop."""

    def __init__(self, deadline: float) -> None:
        self.deadline = deadline
        self.loop_start: float | None = None
        self.n_gaussians = 0
        self.steps: list[tuple[int, float]] = []  # (iteration, perf_counter seconds)

    def log_params(self, params: dict[str, Any]) -> None:
        if "n_gaussians_init" in params:  # logged once, before the loop (render_stage comes later)
            self.loop_start = time.perf_counter()
            self.n_gaussians = int(params["n_gaussians_init"])

    def log_metrics(self, metrics: dict[str, float], step: int | None = None) -> None:
        if step is None:
            return
        if not self.steps or step > self.steps[-1][0]:
            self.steps.append((step, time.perf_counter()))
        if time.time() >= self.deadline:
            raise DeadlineReached(f"deadline reached at iteration {step}")

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        pass

    def set_tags(self, tags: dict[str, str]) -> None:
        pass

    def rate(self) -> float:
        """Iterations per second between the first and the last logged step (the first interval,
        which holds the kernels' warm-up, left out when there are three or more)."""
        pts = self.steps[1:] if len(self.steps) >= 3 else self.steps
        if len(pts) >= 2:
            (s0, t0), (s1, t1) = pts[0], pts[-1]
            return (s1 - s0) / max(t1 - t0, 1e-9)
        if pts and self.loop_start is not None:
            return pts[0][0] / max(pts[0][1] - self.loop_start, 1e-9)
        return float("nan")


def timed_training(overrides: list[str], out_dir: Path, seconds: float) -> dict[str, Any]:
    """Train ``conf/train.yaml`` + ``overrides`` into ``out_dir`` until ``seconds`` have passed
    (scene loading and initialisation included) or the run ends; returns what was measured."""
    from ftgspp.data.load import load_scene
    from ftgspp.trainer import train
    from harness.spec.schema import compose, to_train_config

    start = time.time()
    cfg = to_train_config(compose(overrides))
    cfg.out_dir = str(out_dir)
    cfg.progress = False
    cuda = torch.cuda.is_available()
    if cuda:
        torch.cuda.reset_peak_memory_stats()
    tracker = DeadlineTracker(start + seconds)
    t_load = time.perf_counter()
    scene = load_scene(cfg.data)
    load_seconds = time.perf_counter() - t_load
    status = "deadline"
    try:
        result = train(cfg, scene, tracker)
        status = result.status
    except DeadlineReached:
        pass
    init_seconds = (tracker.loop_start - t_load - load_seconds) if tracker.loop_start else float("nan")
    return {
        "status": status, "iterations_planned": cfg.iterations, "iterations_done": tracker.steps[-1][0] if tracker.steps else 0,
        "iters_per_second": tracker.rate(), "n_gaussians": tracker.n_gaussians, "scene_load_seconds": load_seconds,
        "init_seconds": init_seconds, "wall_seconds": time.time() - start, "width": scene.cameras[0].width,
        "height": scene.cameras[0].height, "n_cameras": len(scene.cameras), "backend": cfg.backend,
        "peak_gpu_allocated_gib": torch.cuda.max_memory_allocated() / 2**30 if cuda else None,
        "peak_gpu_reserved_gib": torch.cuda.max_memory_reserved() / 2**30 if cuda else None,
    }  # fmt: skip


def render_speed(n: int, width: int, height: int, repeats: int = 5, warmup: int = 1, seed: int = 0,
                 backends: tuple[str, ...] = ("gsplat", "cpu")) -> dict[str, Any]:
    """Median forward / forward + backward milliseconds of ``backends`` on ``ftgspp bench
    render``'s scene; gsplat's inputs and cotangents live on the GPU (no copies timed)."""
    from ftgspp.bench.random_scene import project_scene, random_scene
    from ftgspp.bench.timing import time_backend

    inputs = project_scene(random_scene(n, width, height, seed))
    g = torch.Generator().manual_seed(seed + 1)
    cot = (torch.randn(height, width, inputs["colors"].shape[1], generator=g),
           torch.randn(height, width, 1, generator=g), torch.randn(height, width, 1, generator=g))  # fmt: skip
    result: dict[str, Any] = {"n": n, "width": width, "height": height, "repeats": repeats, "backends": {},
                              "n_visible": int((inputs["radii"] > 0).all(-1).sum())}  # fmt: skip
    for name in backends:
        if name == "gsplat":
            from ftgspp.render.gsplat_adapter import rasterize

            dev = "cuda" if torch.cuda.is_available() else "cpu"  # cpu: the stand-ins of a dry run
            args = {k: v.to(dev) if isinstance(v, torch.Tensor) else v for k, v in inputs.items()}
            cotangents = tuple(c.to(dev) for c in cot)
        else:
            from ftgspp.render.cpu import rasterize

            args, cotangents = inputs, cot
        for _ in range(warmup):
            time_backend(rasterize, args, cotangents)
        fwd, fwd_bwd = zip(*(time_backend(rasterize, args, cotangents) for _ in range(repeats)))
        result["backends"][name] = {"fwd_ms": statistics.median(fwd), "fwd_bwd_ms": statistics.median(fwd_bwd)}
    t = result["backends"]
    if "gsplat" in t and "cpu" in t:
        result["cpu_over_gsplat"] = {k: t["cpu"][k] / t["gsplat"][k] for k in ("fwd_ms", "fwd_bwd_ms")}
    return result


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``python -m harness.run.gpu_speed`` (``render`` and ``train``)."""
    parser = argparse.ArgumentParser(prog="python -m harness.run.gpu_speed", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    render = sub.add_parser("render")
    render.add_argument("--n", type=int, default=500_000)
    render.add_argument("--width", type=int, default=1352)
    render.add_argument("--height", type=int, default=1014)
    render.add_argument("--repeats", type=int, default=5)
    render.add_argument("--backends", default="gsplat,cpu")
    train = sub.add_parser("train")
    train.add_argument("--seconds", type=float, required=True, help="wall-clock seconds, scene loading included")
    train.add_argument("--out", type=Path, required=True)
    train.add_argument("overrides", nargs="*")
    return parser


def main(argv: list[str] | None = None) -> int:
    """``render`` or ``train`` (module docstring); prints one JSON line."""
    args = build_parser().parse_args(argv)
    if args.command == "render":
        result = render_speed(args.n, args.width, args.height, args.repeats,
                              backends=tuple(b for b in args.backends.split(",") if b))  # fmt: skip
    else:
        result = timed_training(args.overrides, args.out, args.seconds)
    print(json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
