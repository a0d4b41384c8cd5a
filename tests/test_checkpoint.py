"""A trained model written by ``checkpoint.save_*`` reads back bit for bit with ``load_run``, and its
colour correction with ``load_colour_correction``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ftgspp.checkpoint import load_colour_correction, load_run, save_config, save_model
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


@pytest.mark.parametrize("gauge", ["free", "mean_identity"])
def test_a_saved_colour_correction_loads_back_to_the_same_transforms(tmp_path, gauge):
    cfg = TrainConfig()
    cfg.model.color_correction, cfg.model.cc_gauge = True, gauge
    gen = torch.Generator().manual_seed(1)
    cc = ColorCorrection(4, gauge=gauge)
    with torch.no_grad():
        cc.delta.copy_(0.1 * torch.randn(4, 3, 3, generator=gen))
        cc.bias.copy_(0.1 * torch.randn(4, 3, generator=gen))
    model = FreeTimeGaussians.from_points(np.zeros((2, 3)), np.full((2, 3), 0.5), np.zeros(2), np.zeros((2, 3)),
                                          np.ones(2), cfg.model, cfg.init)  # fmt: skip
    save_model(model, cc, tmp_path)
    loaded = load_colour_correction(tmp_path, cfg, 4)
    assert loaded.gauge == gauge
    image = torch.rand(5, 6, 3, generator=gen)
    for cam in range(4):  # the same transform in use, in either gauge
        torch.testing.assert_close(loaded(image, cam), cc(image, cam), atol=1e-6, rtol=0)
    with pytest.raises(InputError, match="4 cameras, but the scene has 3 training cameras"):
        load_colour_correction(tmp_path, cfg, 3)
    cfg.model.color_correction = False
    assert load_colour_correction(tmp_path, cfg, 4) is None
