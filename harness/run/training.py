"""One training run from a typed config: load the scene it names, train it into a folder.

Both ``ftgspp train`` (``cli.train``) and every job of a study (``run.task``) train through
``run_training``.
"""

from __future__ import annotations

from pathlib import Path

from ftgspp.config import TrainConfig
from ftgspp.tracker import NullTracker, RunResult, Tracker
from harness.run.heap import settled_heap


def run_training(cfg: TrainConfig, out_dir: Path, tracker: Tracker | None = None) -> RunResult:
    """Load the scene named by ``cfg.data`` and train it, writing into ``out_dir``.

    The process's garbage collector is settled around its first run (``run.heap``): a worker
    that makes many runs, or exits after them, does not walk its long-lived objects again."""
    cfg.out_dir = str(out_dir)
    with settled_heap():  # around a call, so that the scene and the model are gone before the freeze
        result = _load_and_train(cfg, tracker or NullTracker())
    return result


def _load_and_train(cfg: TrainConfig, tracker: Tracker) -> RunResult:
    from ftgspp.data.load import load_scene
    from ftgspp.trainer import train

    return train(cfg, load_scene(cfg.data), tracker)
