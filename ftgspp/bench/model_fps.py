"""How fast a trained model renders, and how big it is: the cost axes of a speed-accuracy chart.

``measure(run_dir)`` loads a finished run (``ftgspp.checkpoint.load_run``) and its scene, then
renders every held-out (camera, frame) pair at evaluation resolution with the run's backend,
once with one thread and once with every core this process may use (PyTorch's threads and the
``cpu`` backend's Numba threads together), after one warm-up frame each; passes repeat until
``min_seconds`` have gone by. Frames per second are frames rendered over wall seconds. Nothing
else should run on the machine meanwhile (``study measure`` runs one model at a time).

Size: the bytes of the trained model on disk (the parameters and, where there is one, the
learned colour correction). Used Gaussians (alive, not faded) are the run's own metrics.
"""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import torch

from ftgspp.checkpoint import COLOR_BIAS, COLOR_MATRICES, GAUSSIANS

# the parameters and the learned colour correction: what a trained run keeps (evaluation renders
# without the colour correction, but a model shipped for its training views needs it)
MODEL_FILES = (GAUSSIANS, COLOR_MATRICES, COLOR_BIAS)


def cores() -> int:
    """CPUs this process may run on."""
    return len(os.sched_getaffinity(0))


@contextmanager
def threads(n: int) -> Iterator[None]:
    """PyTorch and Numba at ``n`` threads inside the block, restored after."""
    import numba

    before_torch, before_numba = torch.get_num_threads(), numba.get_num_threads()
    torch.set_num_threads(n)
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        yield
    finally:
        torch.set_num_threads(before_torch)
        numba.set_num_threads(before_numba)


def model_bytes(run_dir: Path) -> int:
    """Bytes of the trained model's files in ``run_dir`` (``MODEL_FILES`` that exist)."""
    return sum((Path(run_dir) / name).stat().st_size for name in MODEL_FILES if (Path(run_dir) / name).is_file())


@torch.no_grad()
def frames_per_second(model, scene, cfg, n_threads: int, min_seconds: float = 0.5) -> float:
    """Held-out frames rendered per wall second at ``n_threads`` (one warm-up frame first)."""
    from ftgspp.view import render_view

    background = torch.tensor(cfg.background, dtype=torch.float32)
    pairs = [(c, f) for c in scene.test_ids for f in range(scene.n_frames)]

    def draw(cam_idx: int, frame: int) -> None:
        render_view(model, scene.cameras[cam_idx], float(scene.times[frame]), cfg.model.sh_degree, background,
                    cfg.backend)

    with threads(n_threads):
        draw(*pairs[0])
        done, t0 = 0, time.perf_counter()
        while True:
            for pair in pairs:
                draw(*pair)
            done += len(pairs)
            elapsed = time.perf_counter() - t0
            if elapsed >= min_seconds:
                return done / elapsed


def measure(run_dir: str | Path, min_seconds: float = 0.5) -> dict[str, float]:
    """``render_fps_1thread``, ``render_fps_all_cores`` (at ``cores()`` threads), ``render_cores``
    and ``model_bytes`` of the finished run in ``run_dir``."""
    from ftgspp.checkpoint import load_run
    from ftgspp.data.load import load_scene

    model, cfg = load_run(run_dir)
    scene = load_scene(cfg.data)
    n = cores()
    return {
        "render_fps_1thread": frames_per_second(model, scene, cfg, 1, min_seconds),
        "render_fps_all_cores": frames_per_second(model, scene, cfg, n, min_seconds),
        "render_cores": float(n),
        "model_bytes": float(model_bytes(Path(run_dir))),
    }
