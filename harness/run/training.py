"""One training run from a typed config: load the scene it names, train it into a folder.

Both ``ftgspp train`` (``cli.train``) and every job of a study (``run.task``) train through
``run_training``.
"""

from __future__ import annotations

from pathlib import Path

from ftgspp.config import TrainConfig
from ftgspp.tracker import NullTracker, RunResult, Tracker


def run_training(cfg: TrainConfig, out_dir: Path, tracker: Tracker | None = None) -> RunResult:
    """Load the scene named by ``cfg.data`` and train it, writing into ``out_dir``."""
    from ftgspp.data.load import load_scene
    from ftgspp.trainer import train

    cfg.out_dir = str(out_dir)
    scene = load_scene(cfg.data)
    return train(cfg, scene, tracker or NullTracker())
