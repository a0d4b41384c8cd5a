"""The trainer's pieces, each against an independent computation.

Device placement (every tensor on the parameters' device), evaluation that survives
images too small for a metric's network, what is saved before optional metrics, the
scene extent, learning rates and their decay, the loss terms and weights, the SH-degree,
relocation and colour-correction schedules inside the loop, and the LPIPS loss gradient.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math

import numpy as np
import pytest
import torch
from test_trainer import params, small_cfg

import ftgspp.trainer as trainer
from ftgspp.colour_correction import ColorCorrection
from ftgspp.config import DataConfig, LossConfig
from ftgspp.data.load import load_scene
from ftgspp.data.synthetic.build import generate
from ftgspp.errors import InputError
from ftgspp.evaluate import evaluate
from ftgspp.image_metrics import lpips_distance, ssim_same
from ftgspp.methods.freetime import FreeTimeGaussians
from ftgspp.train_state import make_optimizer, scene_extent, set_learning_rates
from ftgspp.trainer import loss_terms, sh_degree_at, train

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


class Recorder:
    """A tracker that keeps every logged metric with its step."""

    def __init__(self) -> None:
        self.metrics: list[tuple[int | None, dict]] = []

    def log_params(self, params):
        pass

    def log_metrics(self, metrics, step=None):
        self.metrics.append((step, dict(metrics)))

    def log_artifact(self, path, artifact_path=None):
        pass

    def set_tags(self, tags):
        pass


def full_featured(cfg):
    """Gate + 1 s bound, colour correction from iteration 8, relocation every 5 iterations."""
    cfg.model.gate, cfg.model.max_duration = True, 1.0
    cfg.model.color_correction, cfg.model.cc_start_iter = True, 8
    cfg.strategy.refine_every, cfg.strategy.refine_start_iter = 5, 2
    return cfg


@pytest.mark.parametrize("device", DEVICES)
def test_every_tensor_is_created_on_the_parameters_device(device, tiny_scene_dir, tiny_scene, tmp_path):
    """With torch's default device set to ``meta``, any tensor made without ``device=`` is a
    meta tensor, and mixing it with the (real) parameters fails: so this run through state,
    relocation, colour correction, evaluation and diagnostics proves every constructor
    names its device, as a CUDA run needs, on a CPU-only machine."""
    cfg = full_featured(small_cfg(tiny_scene_dir, tmp_path, iterations=16, device=device, backend="auto"))
    with torch.device("meta"):
        result = train(cfg, tiny_scene)
    assert result.status == "FINISHED" and math.isfinite(result.metrics["psnr"])
    matrices = np.load(tmp_path / "color_correction.npy")
    assert not np.allclose(matrices, np.eye(3)), "colour correction trained after cc_start_iter"


def test_images_too_small_for_lpips_give_nan_and_a_warning_not_a_crash(tmp_path, caplog, lpips_weights):
    """A 64x48 EasyVolcap scene at half resolution is 32x24: below AlexNet's 31-pixel minimum."""
    scene_dir = generate(tmp_path / "scene", layout="easyvolcap", preset="studio", seed=0,
                         width=64, height=48, n_frames=4, n_cameras=5)
    cfg = small_cfg(scene_dir, tmp_path / "run", iterations=6, diagnostics=False)
    cfg.data.downsample = 2
    scene = load_scene(DataConfig(path=str(scene_dir), downsample=2))
    assert scene.cameras[0].width == 32 and scene.cameras[0].height == 24
    with caplog.at_level(logging.WARNING, logger="ftgspp.image_metrics"):
        result = train(cfg, scene)
    assert result.status == "FINISHED"
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert math.isfinite(saved["psnr"]) and math.isfinite(saved["ssim1"])
    assert math.isnan(saved["lpips_alex"]) and math.isnan(saved["lpips_alex_01"])
    assert math.isfinite(saved["lpips_vgg"]), "VGG takes 16 pixels and up"
    warnings = [r.getMessage() for r in caplog.records if "LPIPS-alex" in r.getMessage()]
    assert len(warnings) == 1 and "\n" not in warnings[0] and "32x24" in warnings[0]


def test_eval_lpips_scores_only_the_networks_it_names(tiny_scene_dir, tiny_scene, tmp_path, lpips_weights):
    cfg = small_cfg(tiny_scene_dir, tmp_path, iterations=2, diagnostics=False)
    cfg.eval_lpips = ["alex"]
    metrics = train(cfg, tiny_scene).metrics
    assert {"lpips_alex", "lpips_alex_01"} <= set(metrics)
    assert not any(k.startswith("lpips_vgg") for k in metrics), "VGG16 was not asked for"
    cfg.eval_lpips = []
    assert not any(k.startswith("lpips") for k in train(cfg, tiny_scene).metrics)


def test_an_unknown_eval_lpips_network_is_an_input_error_before_training(tiny_scene_dir, tiny_scene, tmp_path):
    cfg = small_cfg(tiny_scene_dir, tmp_path, iterations=2, diagnostics=False)
    cfg.eval_lpips = ["alex", "squeeze"]
    with pytest.raises(InputError, match="squeeze"):
        train(cfg, tiny_scene)
    assert not (tmp_path / "gaussians.pt").exists()


def test_model_and_core_metrics_are_on_disk_before_optional_metrics_run(tiny_scene_dir, tiny_scene, tmp_path,
                                                                       monkeypatch):
    def exploding_lpips(model, scene, cfg, renders=None):
        assert (tmp_path / "gaussians.pt").exists()
        assert "psnr" in json.loads((tmp_path / "metrics.json").read_text())
        raise RuntimeError("optional metric failed")

    monkeypatch.setattr(trainer, "evaluate_lpips", exploding_lpips)
    with pytest.raises(RuntimeError, match="optional metric failed"):
        train(small_cfg(tiny_scene_dir, tmp_path, iterations=4, diagnostics=False), tiny_scene)
    assert math.isfinite(json.loads((tmp_path / "metrics.json").read_text())["psnr"])


def test_scene_extent_uses_the_training_cameras_only(tiny_scene):
    centres = np.stack([tiny_scene.cameras[i].center for i in tiny_scene.train_ids])
    expected = 1.1 * max(np.linalg.norm(c - centres.mean(0)) for c in centres)
    assert scene_extent(tiny_scene) == pytest.approx(expected, rel=1e-12)
    far = list(tiny_scene.cameras)
    for i in tiny_scene.test_ids:  # move every held-out camera far away: nothing changes
        far[i] = dataclasses.replace(far[i], T=far[i].T + np.array([500.0, 0.0, 0.0]))
    moved = dataclasses.replace(tiny_scene, cameras=far)
    assert np.linalg.norm(moved.cameras[tiny_scene.test_ids[0]].center - tiny_scene.cameras[tiny_scene.test_ids[0]].center) > 100
    assert scene_extent(moved) == scene_extent(tiny_scene)


def test_learning_rates_scale_with_extent_and_decay_to_the_final_ratio(tiny_scene_dir, tmp_path):
    cfg = small_cfg(tiny_scene_dir, tmp_path, iterations=200)
    cfg.lr.scale = 3.0
    n = 10
    model = FreeTimeGaussians.from_points(np.zeros((n, 3)), np.full((n, 3), 0.5), np.zeros(n), np.zeros((n, 3)),
                                          np.ones(n), cfg.model, cfg.init)
    cc = ColorCorrection(4)
    opt = make_optimizer(model, cc, cfg, extent=2.5)
    lr = {g["name"]: g["lr"] for g in opt.param_groups}
    assert lr["means"] == pytest.approx(1.6e-4 * 3.0 * 2.5) and lr["velocities"] == pytest.approx(1.6e-3 * 3.0 * 2.5)
    assert lr["opacities"] == pytest.approx(5e-2 * 3.0) and lr["shN"] == pytest.approx(1.25e-4 * 3.0)
    assert lr["cc"] == pytest.approx(1e-3) and "gates" not in lr  # CC keeps its own rate; no gate: not optimised
    cfg.lr.cc_scaled = True  # the option the collapse study measures: lr.scale multiplies CC's rate too
    assert {g["name"]: g["lr"] for g in make_optimizer(model, cc, cfg, extent=2.5).param_groups}["cc"] == \
        pytest.approx(1e-3 * 3.0)
    cfg.lr.cc_scaled = False
    set_learning_rates(opt, 100, cfg)  # half way: sqrt of the final ratio 0.01
    mid = {g["name"]: g["lr"] for g in opt.param_groups}
    assert mid["means"] == pytest.approx(lr["means"] * 0.1) and mid["velocities"] == pytest.approx(lr["velocities"] * 0.1)
    assert mid["scales"] == lr["scales"] and mid["cc"] == lr["cc"]
    set_learning_rates(opt, 200, cfg)
    end = {g["name"]: g["lr"] for g in opt.param_groups}
    assert end["means"] == pytest.approx(lr["means"] * 0.01) and end["quats"] == lr["quats"]


def test_the_trained_run_used_the_decayed_rates(tiny_scene_dir, tiny_scene, tmp_path):
    cfg = small_cfg(tiny_scene_dir, tmp_path, iterations=20, diagnostics=False)
    train(cfg, tiny_scene)
    blob = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    groups = {g["name"]: g for g in blob["optimizer"]["param_groups"]}
    extent = scene_extent(tiny_scene)
    assert groups["means"]["lr"] == pytest.approx(1.6e-4 * extent * 0.01 ** (19 / 20))  # last step: it = 19
    assert groups["quats"]["lr"] == pytest.approx(1e-3)


def test_loss_terms_and_weights(tiny_scene_dir):
    cfg = small_cfg(tiny_scene_dir, ".")
    cfg.model.gate, cfg.model.max_duration = True, 1.0
    cfg.loss = LossConfig(ssim=0.2, opacity_reg=0.03, scale_reg=0.05, gate_reg=0.007, cc_reg=0.02)
    n = 6
    gen = torch.Generator().manual_seed(0)
    model = FreeTimeGaussians.from_points(torch.rand(n, 3, generator=gen).numpy(), np.full((n, 3), 0.5),
                                          np.linspace(0, 1, n), np.zeros((n, 3)), np.ones(n), cfg.model, cfg.init)
    with torch.no_grad():
        model.params["gates"].copy_(torch.randn(n, generator=gen))
        model.params["scales"].copy_(torch.randn(n, 3, generator=gen))
    g = model.at_time(0.4)
    image, gt = torch.rand(16, 16, 3, generator=gen), torch.rand(16, 16, 3, generator=gen)
    cc = ColorCorrection(2)
    with torch.no_grad():
        cc.delta.copy_(0.1 * torch.randn(2, 3, 3, generator=gen))
        cc.bias.copy_(0.1 * torch.randn(2, 3, generator=gen))
    terms = loss_terms(cfg, model, g, image, gt, cc)
    # independent numbers (numpy / closed forms) for every term
    opacity = 1 / (1 + np.exp(-model.params["opacities"].detach().numpy()))
    gate = 1 / (1 + np.exp(-20.0 * model.params["gates"].detach().numpy()))
    dt = (0.4 - model.params["times"].detach().numpy()) / (1.0 / 6 / (1 + np.exp(-model.params["durations"].detach().numpy())))
    phi = gate + (1 - gate) * np.exp(-0.5 * dt**2)
    l1 = np.abs(image.numpy() - gt.numpy()).mean()
    expected = {
        "l1": l1,
        "opacity": (opacity * phi).mean(),
        "scale": np.exp(model.params["scales"].detach().numpy()).mean(),
        "gate": (1 - gate).mean(),
        "cc": (cc.delta.detach().numpy() ** 2).sum() + (cc.bias.detach().numpy() ** 2).sum(),
    }
    for key, value in expected.items():
        assert terms[key].item() == pytest.approx(value, rel=1e-5), key
    ssim = ssim_same(image, gt).item()
    total = 0.8 * l1 + 0.2 * (1 - ssim) + 0.03 * expected["opacity"] + 0.05 * expected["scale"] \
        + 0.007 * expected["gate"] + 0.02 * expected["cc"]
    assert terms["total"].item() == pytest.approx(total, rel=1e-5)
    cfg.model.gate = False  # without the gate and the correction their terms are absent
    assert set(loss_terms(cfg, model, g, image, gt, None)) == {"photometric", "l1", "opacity", "scale", "total"}


def test_sh_degree_relocation_and_colour_correction_schedules_in_the_loop(tiny_scene_dir, tiny_scene, tmp_path,
                                                                         monkeypatch):
    seen_degrees: list[int] = []
    cc_in_loss: list[bool] = []
    real_render, real_terms = trainer.render_view, trainer.loss_terms

    def recording_render(model, cam, t, sh_degree, **kw):
        seen_degrees.append(sh_degree)
        return real_render(model, cam, t, sh_degree, **kw)

    def recording_terms(cfg, model, g, image, gt, cc=None, lpips_net=None):
        cc_in_loss.append(cc is not None)
        return real_terms(cfg, model, g, image, gt, cc, lpips_net)

    monkeypatch.setattr(trainer, "render_view", recording_render)
    monkeypatch.setattr(trainer, "loss_terms", recording_terms)
    cfg = full_featured(small_cfg(tiny_scene_dir, tmp_path, iterations=40, diagnostics=False))
    cfg.sh_degree_interval, cfg.strategy.refine_stop_iter = 7, 31
    rec = Recorder()
    result = train(cfg, tiny_scene, rec)
    assert seen_degrees[:40] == [min(3, it // 7) for it in range(40)]
    assert [sh_degree_at(cfg, it) for it in (0, 6, 7, 20, 21, 39)] == [0, 0, 1, 2, 3, 3]
    assert [s for s, m in rec.metrics if "relocated" in m] == [5, 10, 15, 20, 25, 30]  # 2 < step < 31
    per_step = sum(m["relocated"] for _, m in rec.metrics if "relocated" in m)
    assert result.metrics["relocated_total"] == per_step  # the run's total is the sum of what each step moved
    assert cc_in_loss == [step > 8 for step in range(1, 41)]


def test_colour_correction_learns_a_shift_but_evaluation_ignores_it(tmp_path):
    scene_dir = generate(tmp_path / "scene", preset="studio", seed=0, width=64, height=48, n_frames=4, n_cameras=6,
                         color_shift=3.0)
    scene = load_scene(DataConfig(path=str(scene_dir)))
    cfg = small_cfg(scene_dir, tmp_path / "cc", iterations=60, diagnostics=False)
    cfg.model.color_correction, cfg.model.cc_start_iter = True, 20
    result = train(cfg, scene)
    learned = np.load(tmp_path / "cc" / "color_correction.npy")
    assert np.abs(learned - np.eye(3)).max() > 1e-3, "the correction moved away from the identity"
    # the same Gaussians evaluated by the plain evaluator (which has no colour correction)
    model = trainer.TrainState.create(cfg, scene, torch.device("cpu")).model
    with torch.no_grad():
        for k, v in params(tmp_path / "cc").items():
            model.params[k].copy_(v)
    plain, _ = evaluate(model, scene, cfg, tmp_path / "plain")
    assert plain["psnr"] == result.metrics["psnr"] and plain["ssim1"] == result.metrics["ssim1"]
    # and stopping at cc_start_iter leaves the correction untouched
    cfg2 = small_cfg(scene_dir, tmp_path / "early", iterations=20, diagnostics=False)
    cfg2.model.color_correction, cfg2.model.cc_start_iter = True, 20
    train(cfg2, scene)
    assert np.array_equal(np.load(tmp_path / "early" / "color_correction.npy"), np.broadcast_to(np.eye(3), learned.shape))


def test_lpips_loss_gradient_matches_finite_differences(lpips_models):
    """The LPIPS term the trainer adds: d(w · LPIPS(image, gt))/d image along a random
    direction, against a central finite difference of the same function."""
    gen = torch.Generator().manual_seed(0)
    gt = torch.rand(40, 48, 3, generator=gen)
    image = (gt + 0.2 * torch.randn(40, 48, 3, generator=gen)).clamp(0.05, 0.95)
    direction = torch.randn(40, 48, 3, generator=gen)
    direction /= direction.norm()
    net, weight = lpips_models["alex"], 0.01

    def f(x: torch.Tensor) -> torch.Tensor:
        return weight * lpips_distance(net, x.clamp(0, 1), gt)

    x = image.clone().requires_grad_(True)
    f(x).backward()
    analytic = (x.grad * direction).sum().item()
    h = 1e-2
    numeric = (f(image + h * direction).item() - f(image - h * direction).item()) / (2 * h)
    assert abs(analytic) > 1e-6
    assert analytic == pytest.approx(numeric, rel=0.03)
    towards_gt = (x.grad * (gt - image)).sum().item()
    assert towards_gt < 0, "moving the render towards the ground truth lowers the loss"
