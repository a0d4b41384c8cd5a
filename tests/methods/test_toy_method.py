"""A method written outside the ``ftgspp`` package (``tests/methods/toy_static.py``: static
Gaussians) selected by ``model.method=module:Class``: it trains, saves and loads and is
diagnosed, as docs/methods.md describes (``tests/harness/test_outside_method_study.py`` runs it
as a study)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from ftgspp.checkpoint import load_run
from ftgspp.config import ModelConfig, TrainConfig
from ftgspp.errors import InputError
from ftgspp.methods import method_class, method_names, register_method
from ftgspp.trainer import check_config, train
from tests.methods.toy_static import StaticGaussians

TOY = "tests.methods.toy_static:StaticGaussians"

def test_module_paths_and_registered_names_select_the_class() -> None:
    assert method_class(TOY) is StaticGaussians
    register_method("toy_static", StaticGaussians)
    assert method_class("toy_static") is StaticGaussians and "toy_static" in method_names()
    with pytest.raises(TypeError):
        register_method("bad", dict)
    with pytest.raises(InputError, match="cannot import 'tests.methods.nowhere:X'"):
        check_config(TrainConfig(model=ModelConfig(method="tests.methods.nowhere:X")))


def smoke_config(out_dir: Path) -> TrainConfig:
    cfg = TrainConfig(model=ModelConfig(name="toy", method=TOY, sh_degree=0, color_correction=True, cc_start_iter=10),
                      profile="smoke", iterations=30, budget=300, sh_degree_interval=10, checkpoint_every=20,
                      log_every=10, eval_lpips=[], diagnostics_figures=False, progress=False, out_dir=str(out_dir))
    cfg.strategy.refine_every, cfg.strategy.refine_start_iter, cfg.strategy.refine_stop_iter = 10, 10, 25
    cfg.init.max_features = 500
    return cfg


def test_an_outside_method_trains_saves_loads_and_is_diagnosed(tiny_scene, tmp_path: Path) -> None:
    result = train(smoke_config(tmp_path / "run"), tiny_scene)
    assert result.status == "FINISHED"
    m = result.metrics
    assert math.isfinite(m["psnr"]) and m["n_gaussians"] == 300
    assert m["lifetime_median_fraction"] == math.inf  # static Gaussians never fade
    assert m["motion_leak_static"] == 0.0  # and never move
    model, cfg = load_run(tmp_path / "run")
    assert type(model) is StaticGaussians and cfg.model.method == TOY
    assert (tmp_path / "run" / "color_correction.npy").is_file()  # the trainer's correction, on any method
