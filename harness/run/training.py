"""One training run from a typed config: load the scene it names, train it into a folder.

Both ``ftgspp train`` (``cli.train``) and every job of a study (``run.task``) train through
``run_training``. A finished run's tracker gets the tag ``model_digest``: a sha256 of the trained
model's bits (``model_digest`` below), which ``study check`` compares with a committed report's.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from ftgspp.config import TrainConfig
from ftgspp.tracker import NullTracker, RunResult, Tracker
from harness.run.heap import settled_heap


def run_training(cfg: TrainConfig, out_dir: Path, tracker: Tracker | None = None) -> RunResult:
    """Load the scene named by ``cfg.data`` and train it, writing into ``out_dir``.

    The process's garbage collector is settled around its first run (``run.heap``): a worker
    that makes many runs, or exits after them, does not walk its long-lived objects again."""
    cfg.out_dir = str(out_dir)
    tracker = tracker or NullTracker()
    with settled_heap():  # around a call, so that the scene and the model are gone before the freeze
        result = _load_and_train(cfg, tracker)
    if result.status == "FINISHED" and (digest := model_digest(out_dir)):
        tracker.set_tags({"model_digest": digest})
    return result


def model_digest(out_dir: Path) -> str:
    """sha256 (64 hex digits) of the trained model in ``out_dir`` (``ftgspp.checkpoint``): its raw
    parameters by name in sorted order, then the learned colour correction where there is one,
    each as name, dtype, shape and bytes; "" when the folder holds no model. Equal digests:
    the same model, bit for bit."""
    import numpy as np
    import torch

    from ftgspp.checkpoint import COLOR_BIAS, COLOR_MATRICES, GAUSSIANS

    out_dir = Path(out_dir)
    if not (out_dir / GAUSSIANS).is_file():
        return ""
    h = hashlib.sha256()

    def add(name: str, dtype: object, shape: tuple[int, ...], data: bytes) -> None:
        h.update(f"{name}:{dtype}:{tuple(shape)}\0".encode())
        h.update(data)

    params = torch.load(out_dir / GAUSSIANS, map_location="cpu", weights_only=True)
    for name in sorted(params):
        t = params[name].detach().contiguous()  # [N, ...] per Gaussian
        add(name, t.dtype, tuple(t.shape), t.reshape(-1).view(torch.uint8).numpy().tobytes())
    for name in (COLOR_MATRICES, COLOR_BIAS):  # [C, 3, 3], [C, 3]
        if (out_dir / name).is_file():
            a = np.ascontiguousarray(np.load(out_dir / name, allow_pickle=False))
            add(name, a.dtype, a.shape, a.tobytes())
    return h.hexdigest()


def _load_and_train(cfg: TrainConfig, tracker: Tracker) -> RunResult:
    from ftgspp.data.load import load_scene
    from ftgspp.trainer import train

    return train(cfg, load_scene(cfg.data), tracker)
