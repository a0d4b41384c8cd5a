"""Compile the ``cpu`` backend's Numba kernels ahead of the runs that need them.

The kernels compile on first use (about a minute on an idle 2-core machine) and are cached on
disk. A study would otherwise start with every worker compiling them at once and printing
nothing for minutes; ``study run`` instead checks ``kernels_cached()`` and, when the cache is
cold, says so and runs ``python -m ftgspp.bench.warmup`` first, which calls every kernel once
on tiny inputs (the rasterizer forward and backward, the fused prepare nodes of FreeTimeGS and
STGS, the SSIM loss, the colour-aligned PSNR's fit, the relocation statistics).

    python -m ftgspp.bench.warmup        # prints the seconds it took

On two or more cores the cold compile runs in two processes at once: the methods' fused stages
(FreeTimeGS's and STGS's, which share the projection and SH blocks) in a child, every other
kernel (the rasterizer, SSIM, colour alignment, relocation statistics) in this one; each writes
its kernels to the shared on-disk cache. Figures (2-core AMD EPYC, AVX-512, LLVM ``znver4``):
BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

# every kernel compiled cold, in two processes on an idle 2-core AMD EPYC with AVX-512 (LLVM
# znver4; BENCHMARKS.md, `python -m ftgspp.bench.warmup`)
COLD_COMPILE_S = 44.0
PARTS = ("fused", "rest")  # the two halves of the cold compile (``warm_up(part)``)


def _dispatchers() -> list:
    from ftgspp import colour_alignment, ssim_cpu
    from ftgspp.methods import freetime_fused, stg_fused
    from ftgspp.render import cpu_kernels
    from ftgspp.strategy import relocate

    return [cpu_kernels.bin_gaussians, cpu_kernels.render_forward, cpu_kernels.render_backward,
            cpu_kernels.reduce_pair_grads, freetime_fused.prepare_forward, freetime_fused.prepare_backward,
            stg_fused.prepare_forward, stg_fused.prepare_backward,
            ssim_cpu.ssim_forward, ssim_cpu.ssim_backward, colour_alignment.normal_equations,
            colour_alignment.cholesky_solve, colour_alignment.apply_affine, relocate._add_visible]


def kernels_cached() -> bool:
    """Whether Numba's on-disk cache holds every kernel for the current sources (a best guess:
    it reads Numba's cache index, whose stamp changes when a kernel's source file does)."""
    try:
        return all(bool(d._cache._cache_file._load_index()) for d in _dispatchers())
    except Exception:  # another Numba layout: assume cold and warm up (harmless when cached)
        return False


def warm_up(part: str | None = None) -> float:
    """Call every kernel once (``part``: only the methods' fused stages, "fused", or every other
    kernel, "rest"); returns the seconds it took (compile time when the cache was cold)."""
    if part not in (None, *PARTS):
        raise ValueError(f"unknown warm-up part {part!r} (one of {PARTS})")
    import numpy as np
    import torch

    from ftgspp.bench.random_scene import random_scene
    from ftgspp.bench.stages import stage_model
    from ftgspp.colour_alignment import colour_aligned_np
    from ftgspp.config import InitConfig, ModelConfig
    from ftgspp.image_metrics import ssim_same
    from ftgspp.methods.freetime_fused import prepare
    from ftgspp.methods.stg import SpacetimeGaussians
    from ftgspp.methods.stg_fused import prepare as stg_prepare
    from ftgspp.render import cpu
    from ftgspp.render.contract import CameraTensors
    from ftgspp.strategy import relocate

    t0 = time.perf_counter()
    scene = random_scene(4, 32, 24)
    camera = CameraTensors(scene["viewmat"], scene["K"], torch.zeros(3), 32, 24)
    if part != "rest":  # the two methods' fused stages, which share the projection and SH blocks
        p = prepare(stage_model(scene, 0).params, 0.5, camera, 3, 1.0, True, 20.0)
        (p.means2d.sum() + p.colors.sum()).backward()
        stg = SpacetimeGaussians.from_points(np.zeros((4, 3)), np.full((4, 3), 0.5), np.zeros(4), np.zeros((4, 3)),
                                             np.ones(4), ModelConfig(name="stg", method="stg", sh_degree=0),
                                             InitConfig())
        q = stg_prepare(stg.params, 0.5, camera)
        (q.means2d.sum() + q.colors.sum()).backward()
    if part == "fused":
        return time.perf_counter() - t0
    means2d = torch.tensor([[8.0, 8.0], [20.0, 9.0]], requires_grad=True)
    out = cpu.rasterize(means2d, torch.tensor([[0.1, 0.0, 0.1]] * 2), torch.rand(2, 3), torch.rand(2),
                        torch.ones(2), torch.tensor([[6, 6], [6, 6]]), 32, 24)  # radii [N, 2]
    sum(o.sum() for o in out).backward()
    (1 - ssim_same(torch.rand(16, 16, 3, requires_grad=True), torch.rand(16, 16, 3))).backward()
    colour_aligned_np(np.random.default_rng(0).random((64, 3)), np.random.default_rng(1).random((64, 3)))
    relocate._add_visible(np.zeros(2, np.float32), np.zeros(2, np.float32), np.ones(2, np.float32),
                          np.array([[2, 2], [0, 0]], np.int32))  # radii as the fused stages give them
    return time.perf_counter() - t0


def warm_up_parallel(jobs: int | None = None) -> float:
    """``warm_up`` with its two parts in two processes at once when there are ``jobs`` >= 2
    (default: 2 on a machine with 2 cores or more): the fused stages in a child, the rest here.
    Returns the seconds until both are done; a failed child raises with its last line."""
    jobs = jobs if jobs is not None else min(2, os.cpu_count() or 1)
    if jobs < 2:
        return warm_up()
    t0 = time.perf_counter()
    child = subprocess.Popen([sys.executable, "-m", "ftgspp.bench.warmup", "--part", "fused"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        warm_up("rest")
    finally:
        _, err = child.communicate()
    if child.returncode != 0:
        raise RuntimeError(f"the fused stages' warm-up failed: {(err.strip().splitlines() or ['no output'])[-1]}")
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ftgspp.bench.warmup", description=__doc__.split("\n\n")[0])
    parser.add_argument("--part", choices=PARTS, default=None, help="only this half of the kernels, in this process")
    parser.add_argument("--jobs", type=int, default=None, help="processes (default: 2 on 2 cores or more)")
    args = parser.parse_args(argv)
    seconds = warm_up(args.part) if args.part else warm_up_parallel(args.jobs)
    print(f"{seconds:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
