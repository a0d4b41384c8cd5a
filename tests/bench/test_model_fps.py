"""``ftgspp.bench.model_fps``: render speed and size of a trained run, on a tiny saved model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ftgspp.bench.model_fps import MODEL_FILES, measure, model_bytes, threads
from ftgspp.checkpoint import save_config, save_model
from ftgspp.config import DataConfig, ModelConfig, TrainConfig
from ftgspp.methods.freetime import FreeTimeGaussians
from harness.run.known_size import generate


def _run_folder(tmp_path: Path) -> Path:
    scene = generate(tmp_path / "scene", k=20, n_cameras=3, n_frames=3, width=32, height=24)
    truth = np.load(scene / "known_size.npz")
    points = truth["means"]
    cfg = TrainConfig(data=DataConfig(path=str(scene), downsample=1), model=ModelConfig(sh_degree=0))
    model = FreeTimeGaussians.from_points(points, truth["colors"], np.zeros(len(points)), truth["velocities"],
                                          np.full(len(points), 0.05), cfg.model, cfg.init)
    run = tmp_path / "run"
    run.mkdir()
    save_config(cfg, run)
    save_model(model, None, run)
    return run


def test_measure_reports_positive_rates_and_the_model_files_bytes(tmp_path: Path) -> None:
    run = _run_folder(tmp_path)
    out = measure(run, min_seconds=0.0)
    assert set(out) == {"render_fps_1thread", "render_fps_all_cores", "render_cores", "model_bytes"}
    assert out["render_fps_1thread"] > 0 and out["render_fps_all_cores"] > 0 and out["render_cores"] >= 1
    assert out["model_bytes"] == (run / MODEL_FILES[0]).stat().st_size == model_bytes(run)


def test_threads_are_restored_after_the_block() -> None:
    import numba

    before = (torch.get_num_threads(), numba.get_num_threads())
    with threads(1):
        assert torch.get_num_threads() == 1 and numba.get_num_threads() == 1
    assert (torch.get_num_threads(), numba.get_num_threads()) == before
