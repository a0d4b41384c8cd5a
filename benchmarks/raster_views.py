"""The `cpu` rasterizer's kernels on the views of a finished run (a trained model, not random Gaussians).

``ftgspp bench render`` times the kernels on 5,000 random Gaussians; a trained model has other
shapes, overlaps and depth orders, and so other per-pair costs. This script loads a finished
training run (``config.json`` + ``gaussians.pt``), renders its training cameras at every
``--stride``-th frame, and times each kernel of the rasterizer on those views, one thread:
binning, the forward pass, the backward pass (with a fixed random image cotangent) and the
per-Gaussian reduction, plus the views' pair statistics. Nothing is asserted: run it in two
checkouts (each imports its own ``ftgspp``) one after the other and compare.

    .venv/bin/python benchmarks/raster_views.py outputs/studies/secret5/<stamp>/<variant>/studio/seed0
    .venv/bin/python benchmarks/raster_views.py RUN_DIR --data data/synth/studio --repeats 5 --json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

KERNELS = ("bin", "forward", "backward", "reduce")


def capture_views(run_dir: Path, stride: int, data: Path | None = None) -> list[tuple]:
    """The rasterizer's numpy inputs for each training camera at every ``stride``-th frame
    (``data``: the scene folder, when the run's relative ``data.path`` does not hold here)."""
    import torch

    from ftgspp.checkpoint import load_run
    from ftgspp.data.load import load_scene
    from ftgspp.render import cpu
    from ftgspp.view import render_view

    model, cfg = load_run(run_dir)
    if data is not None:
        cfg.data.path = str(data)
    scene = load_scene(cfg.data)
    views: list[tuple] = []
    original = cpu._forward

    def keep(*args):
        views.append(tuple(a.copy() if hasattr(a, "copy") else a for a in args))
        return original(*args)

    cpu._forward = keep
    try:
        bg = torch.tensor(cfg.background, dtype=torch.float32)
        with torch.no_grad():
            for c in scene.train_ids:
                for f in range(0, scene.n_frames, stride):
                    render_view(model, scene.cameras[c], float(scene.times[f]), cfg.model.sh_degree, bg, "cpu")
    finally:
        cpu._forward = original
    return views


def time_views(views: list[tuple], repeats: int) -> dict:
    """Median over ``repeats`` of each kernel's mean time per view (ms), and pair statistics."""
    import numpy as np

    from ftgspp.render import cpu_kernels as k
    from ftgspp.render.cpu import depth_sort_keys

    rng = np.random.default_rng(0)
    cotangents = [rng.standard_normal((v[8], v[7], v[2].shape[1])).astype(np.float32) * 1e-3 for v in views]
    per_repeat: dict[str, list[float]] = {name: [] for name in KERNELS}
    stats = {"pairs": 0.0, "live_pairs": 0.0, "rows": 0.0}
    for r in range(repeats + 1):  # the first pass loads the kernels and is not timed
        spent = dict.fromkeys(KERNELS, 0.0)
        for v, g_image in zip(views, cotangents):
            m2d, con, col, opa, dep, bg, rad, w, h = v
            t0 = time.perf_counter()
            b = k.bin_gaussians(m2d, con, opa, rad, w, h)
            t1 = time.perf_counter()
            workers = k.balance_tiles(b.tile_cost, 1)
            t2 = time.perf_counter()
            fw = k.render_forward(m2d, con, col, opa, dep, depth_sort_keys(dep), bg, b.offsets, b.pair_gauss, b.span,
                                  b.rect, b.gauss_off, *workers, w, h)
            t3 = time.perf_counter()
            zeros = np.zeros((h, w), np.float32)
            workers = k.balance_tiles(fw.tile_work, 1)
            t4 = time.perf_counter()
            pair_grads, bg_grads = k.render_backward(m2d, con, col, opa, dep, bg, b.offsets, b.pair_gauss, fw.n_used,
                                                     fw.pair_live, fw.pair_box, *workers, fw.t_final, fw.stop_slot,
                                                     g_image, zeros, zeros)
            t5 = time.perf_counter()
            k.reduce_pair_grads(pair_grads, b.gauss_off, fw.gauss_pairs, bg_grads)
            t6 = time.perf_counter()
            for name, dt in zip(KERNELS, (t1 - t0, t3 - t2, t5 - t4, t6 - t5)):
                spent[name] += dt
            if r == 0:
                live = fw.pair_live == 1
                stats["pairs"] += len(b.pair_gauss) / len(views)
                stats["live_pairs"] += live.sum() / len(views)
                stats["rows"] += np.maximum(fw.pair_box[:, 1] - fw.pair_box[:, 0], 0).sum() / len(views)
        if r > 0:
            for name in KERNELS:
                per_repeat[name].append(1e3 * spent[name] / len(views))
    return {"ms_per_view": {name: statistics.median(v) for name, v in per_repeat.items()},
            "per_view": {key: float(val) for key, val in stats.items()}}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir", type=Path, help="a finished training run (config.json + gaussians.pt)")
    p.add_argument("--data", type=Path, default=None, help="scene folder (default: the run's data.path)")
    p.add_argument("--stride", type=int, default=6, help="every STRIDE-th frame of each training camera")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", action="store_true")
    args = p.parse_args(argv)
    if not (args.run_dir / "config.json").is_file():
        print(f"error: {args.run_dir}: not a finished training run (no config.json)", file=sys.stderr)
        return 2
    if args.stride < 1 or args.repeats < 1:
        print("error: --stride and --repeats must be at least 1", file=sys.stderr)
        return 2
    from ftgspp.errors import InputError

    try:
        views = capture_views(args.run_dir, args.stride, args.data)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not views:
        print(f"error: {args.run_dir}: its scene has no training view to render", file=sys.stderr)
        return 2
    out = {"views": len(views), "commit_root": str(ROOT), **time_views(views, args.repeats)}
    if args.json:
        print(json.dumps(out))
    else:
        ms, pv = out["ms_per_view"], out["per_view"]
        print(f"{len(views)} views of {args.run_dir}, one thread, ms a view (median of {args.repeats}): "
              + ", ".join(f"{name} {ms[name]:.3f}" for name in KERNELS))
        print(f"per view: {pv['pairs']:.0f} (tile, Gaussian) pairs, {pv['live_pairs']:.0f} contributing,"
              f" {pv['rows']:.0f} tile rows in the pairs' row ranges")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # one thread, as a study's workers run (before Numba loads)
    raise SystemExit(main())
