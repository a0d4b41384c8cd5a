"""A trained model written by ``checkpoint.save_*`` reads back bit for bit with ``load_run``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ftgspp.checkpoint import load_run, save_config, save_model
from ftgspp.colour_correction import ColorCorrection
from ftgspp.config import TrainConfig
from ftgspp.errors import InputError
from ftgspp.methods.freetime import FreeTimeGaussians


def test_a_saved_run_loads_back_bit_for_bit(tmp_path):
    cfg = TrainConfig(seed=7)
    cfg.model.gate, cfg.model.max_duration, cfg.loss.cc_reg = True, 1.0, 0.5
    n = 5
    gen = torch.Generator().manual_seed(0)
    model = FreeTimeGaussians.from_points(torch.rand(n, 3, generator=gen).numpy(), np.full((n, 3), 0.5),
                                          np.linspace(0, 1, n), np.zeros((n, 3)), np.ones(n), cfg.model, cfg.init)
    cc = ColorCorrection(3)
    with torch.no_grad():
        cc.delta.copy_(torch.randn(3, 3, 3, generator=gen))
        cc.bias.copy_(torch.randn(3, 3, generator=gen))
    save_config(cfg, tmp_path)
    save_model(model, cc, tmp_path)
    loaded, loaded_cfg = load_run(tmp_path)
    assert loaded_cfg == cfg
    assert loaded.params.keys() == model.params.keys()
    assert all(torch.equal(loaded.params[k], model.params[k].detach()) for k in model.params)
    matrices, bias = np.load(tmp_path / "color_correction.npy"), np.load(tmp_path / "color_bias.npy")
    assert matrices.shape == (3, 3, 3)
    assert np.array_equal(matrices, np.eye(3, dtype=np.float32) + cc.delta.detach().numpy())
    assert np.array_equal(bias, cc.bias.detach().numpy())


def test_a_folder_without_a_model_is_an_input_error(tmp_path):
    save_config(TrainConfig(), tmp_path)
    with pytest.raises(InputError, match="gaussians.pt"):
        load_run(tmp_path)
