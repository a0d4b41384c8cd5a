"""Spacetime Gaussians (lite) against independent oracles: its formulas written out in numpy,
a lifetime measured on a fine time grid, velocities by finite differences, gradients by
``gradcheck``; then rendering through every backend, the trainer, checkpoint and resume."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from ftgspp.checkpoint import load_run
from ftgspp.config import InitConfig, ModelConfig, TrainConfig
from ftgspp.errors import InputError
from ftgspp.methods import method_class
from ftgspp.methods.stg import SpacetimeGaussians
from ftgspp.train_state import make_optimizer
from ftgspp.trainer import train
from ftgspp.view import render_view

STG = ModelConfig(name="stg", method="stg", sh_degree=0)


def random_stg(n: int = 64, seed: int = 0, dtype: torch.dtype = torch.float32) -> SpacetimeGaussians:
    """Gaussians in front of an identity camera, with motion, rotation speed and finite lifetimes."""
    g = torch.Generator().manual_seed(seed)
    u = lambda *shape: torch.rand(*shape, generator=g, dtype=dtype)  # noqa: E731
    means = torch.stack([u(n) * 2 - 1, u(n) * 1.6 - 0.8, 2 + 2 * u(n)], dim=-1)
    params = {
        "means": means,
        "trbf_center": u(n),
        "trbf_scale": torch.log(0.2 + 0.8 * u(n)),
        "motion": 0.3 * (u(n, 9) - 0.5),
        "quats": u(n, 4) + 0.1,
        "omega": 0.5 * (u(n, 4) - 0.5),
        "scales": torch.log(0.05 + 0.15 * u(n, 3)),
        "opacities": 3 * (u(n) - 0.5),
        "rgb": u(n, 3),
    }
    return SpacetimeGaussians(params, STG)


def test_the_method_is_selected_by_name_and_by_module_path() -> None:
    assert method_class("stg") is SpacetimeGaussians
    assert method_class("ftgspp.methods.stg:SpacetimeGaussians") is SpacetimeGaussians
    with pytest.raises(InputError, match="unknown method 'nope'"):
        method_class("nope")
    with pytest.raises(InputError, match="not a DynamicGaussians subclass"):
        method_class("math:pi")
    with pytest.raises(InputError, match="sh_degree must be 0"):
        SpacetimeGaussians(random_stg().params, replace(STG, sh_degree=3))


def test_at_time_follows_the_papers_formulas() -> None:
    model = random_stg()
    p = {k: v.detach().double().numpy() for k, v in model.params.items()}
    t = 0.37
    dt = (t - p["trbf_center"])[:, None]
    m = p["motion"]
    means = p["means"] + m[:, :3] * dt + m[:, 3:6] * dt**2 + m[:, 6:] * dt**3
    phi = np.exp(-(((t - p["trbf_center"]) / np.exp(p["trbf_scale"])) ** 2))
    g = model.at_time(t)
    np.testing.assert_allclose(g.means.detach().numpy(), means, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(g.quats.detach().numpy(), p["quats"] + p["omega"] * dt, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(g.temporal.detach().numpy(), phi, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(g.opacities.detach().numpy(), phi / (1 + np.exp(-p["opacities"])), rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(g.colors.detach().numpy(), p["rgb"])
    assert g.sh0 is None and torch.equal(g.log_scales, model.params["scales"])


def test_velocities_are_the_time_derivative_of_the_positions() -> None:
    model = random_stg(dtype=torch.float64)
    t, h = 0.61, 1e-6
    numeric = (model.at_time(t + h).means - model.at_time(t - h).means) / (2 * h)
    torch.testing.assert_close(model.velocities_at(t), numeric.detach(), rtol=1e-6, atol=1e-8)


def test_lifetimes_match_a_fine_time_grid() -> None:
    model = random_stg(n=32, seed=3)
    theta = 0.05
    with torch.no_grad():
        centre = model.temporal_centres()
        grid = torch.linspace(-4.0, 4.0, 80_001)  # offsets from each centre, seconds
        above = torch.stack([model.base_opacity() * model.temporal_opacity(centre + d) >= theta for d in grid[::10]])
        measured = above.sum(0) * float(grid[10] - grid[0])
        formula = model.lifetimes(theta)
    assert (formula[model.base_opacity() <= theta] == 0).all() and (formula > 0).any()
    np.testing.assert_allclose(measured.numpy(), formula.numpy(), atol=2e-3)


def test_gradients_of_every_parameter_match_finite_differences() -> None:
    model = random_stg(n=6, dtype=torch.float64)
    gen = torch.Generator().manual_seed(2)

    def outputs() -> list[torch.Tensor]:
        g = model.at_time(0.4)
        return [g.means, g.quats, g.opacities, g.colors, g.log_scales, model.velocities_at(0.4)]

    weights = [torch.randn(o.shape, generator=gen, dtype=torch.float64) for o in outputs()]
    loss = lambda: sum((w * o).sum() for w, o in zip(weights, outputs()))  # noqa: E731
    loss().backward()
    h = 1e-6
    for name, p in model.params.items():
        for i in torch.randperm(p.numel(), generator=gen)[:4].tolist():
            flat = p.data.view(-1)
            flat[i] += h
            up = loss().item()
            flat[i] -= 2 * h
            down = loss().item()
            flat[i] += h
            assert p.grad.view(-1)[i].item() == pytest.approx((up - down) / (2 * h), rel=1e-5, abs=1e-7), name


def test_rendering_on_the_cpu_backend_matches_the_reference_with_gradients(tiny_scene) -> None:
    model = random_stg(n=200, seed=1)
    cam = tiny_scene.cameras[0]
    cam_model = SpacetimeGaussians({k: v.detach().clone() for k, v in model.params.items()}, STG)
    # place the Gaussians in front of this camera: camera space -> world
    with torch.no_grad():
        for m in (model, cam_model):
            m.params["means"].copy_(torch.as_tensor((m.params["means"].numpy() - cam.T) @ cam.R, dtype=torch.float32))
    outs = {}
    for backend, m in (("reference", model), ("cpu", cam_model)):
        out, _ = render_view(m, cam, 0.5, 0, backend=backend)
        out.image.square().sum().backward()
        outs[backend] = out
    assert (outs["reference"].alpha > 0.5).any()
    torch.testing.assert_close(outs["cpu"].image, outs["reference"].image, rtol=0, atol=2e-5)
    for name in model.params:
        ref = model.params[name].grad
        assert ref is not None and ref.abs().max() > 0, name
        err = (cam_model.params[name].grad - ref).abs().max() / ref.abs().max()
        assert err < 1e-3, f"{name}: relative error {err:.2g}"


def test_optimizer_groups_use_the_methods_rates(tiny_scene) -> None:
    model = random_stg()
    cfg = TrainConfig(model=STG)
    opt = make_optimizer(model, None, cfg, extent=2.0)
    groups = {g["name"]: g for g in opt.param_groups}
    assert set(groups) == set(model.params)
    assert groups["rgb"]["lr"] == cfg.lr.sh0 and groups["omega"]["lr"] == cfg.lr.omega
    assert groups["motion"]["lr"] == cfg.lr.motion * 2.0 and not groups["motion"]["decays"]
    assert groups["means"]["lr"] == cfg.lr.means * 2.0 and groups["means"]["decays"]
    assert groups["trbf_scale"]["lr"] == cfg.lr.trbf_scale


def test_from_points_starts_as_the_public_lite_model() -> None:
    n = 5
    spacing = np.array([1e-9, 0.01, 0.1, 1.0, 10.0])
    model = SpacetimeGaussians.from_points(np.zeros((n, 3)), np.full((n, 3), 0.25), np.linspace(0, 1, n),
                                           np.ones((n, 3)), spacing, STG, InitConfig())
    np.testing.assert_allclose(model.base_opacity().detach().numpy(), 0.1, rtol=1e-6)
    np.testing.assert_allclose(model.params["scales"][:, 0].detach().numpy(),
                               np.clip(np.log(np.maximum(spacing, 1e-7)), -10, 1), rtol=1e-6)
    assert (model.params["motion"] == 0).all() and (model.params["omega"] == 0).all()  # velocities unused
    assert (model.params["trbf_scale"] == 0).all() and (model.params["rgb"] == 0.25).all()
    torch.testing.assert_close(model.temporal_centres(), torch.linspace(0, 1, n))


def test_the_initial_scales_come_from_the_spacing_model_init_spacing_names(monkeypatch) -> None:
    from ftgspp import train_state
    from ftgspp.init import InitPoints
    from ftgspp.trainer import check_config

    n = 4
    pts = InitPoints(means=np.zeros((n, 3), np.float32), colors=np.full((n, 3), 0.5, np.float32),
                     times=np.zeros(n, np.float32), velocities=np.zeros((n, 3), np.float32),
                     spacing=np.full(n, 0.2, np.float32), union_spacing=np.full(n, 0.01, np.float32),
                     keyframe=np.zeros(n, np.int64))  # fmt: skip
    monkeypatch.setattr(train_state, "initialize", lambda *args, **kwargs: pts)
    for rule, want in ((None, 0.2), ("keyframe", 0.2), ("union", 0.01)):
        cfg = TrainConfig(model=replace(STG, init_spacing=rule))
        model = train_state.build_model(cfg, None, torch.device("cpu"))
        np.testing.assert_allclose(model.params["scales"].detach().numpy(), np.log(np.float32(want)), rtol=1e-6)
    with pytest.raises(InputError, match="model.init_spacing.*unknown rule 'nearest'"):
        check_config(TrainConfig(model=replace(STG, init_spacing="nearest")))


def test_conf_model_stg_starts_from_the_public_codes_spacing() -> None:
    """model=stg is the public code's start: the fused stage and the union spacing (model.init_spacing=union,
    docs/methods.md); FreeTimeGS keeps its per-keyframe spacing (null)."""
    from ftgspp.bench.train_speed import model_config

    cfg = model_config("stg")
    assert (cfg.method, cfg.init_spacing, cfg.fused_stage) == ("stg", "union", True)
    assert model_config("ftgs").init_spacing is None


@pytest.mark.slow
def test_training_improves_saves_and_resumes_exactly(tiny_scene, tmp_path) -> None:
    from tests.test_trainer import StopAt

    cfg = TrainConfig(model=STG, profile="smoke", iterations=40, budget=300, sh_degree_interval=10,
                      checkpoint_every=20, log_every=10, eval_lpips=[], diagnostics=True, diagnostics_figures=False,
                      progress=False, out_dir=str(tmp_path / "run"))
    cfg.strategy.refine_every, cfg.strategy.refine_start_iter, cfg.strategy.refine_stop_iter = 10, 10, 35
    cfg.init.max_features = 500
    result = train(cfg, tiny_scene)
    assert result.status == "FINISHED"
    for key in ("psnr", "psnr_cc", "n_faded", "lifetime_median_fraction", "motion_epe_dynamic"):
        assert math.isfinite(result.metrics[key]), key
    untrained = train(replace(cfg, iterations=0, diagnostics=False, out_dir=str(tmp_path / "init")), tiny_scene)
    assert result.metrics["psnr"] > untrained.metrics["psnr"] + 1.0  # 40 iterations learn something
    model, loaded_cfg = load_run(tmp_path / "run")
    assert isinstance(model, SpacetimeGaussians) and loaded_cfg.model.method == "stg"
    assert set(model.params) == {"means", "trbf_center", "trbf_scale", "motion", "quats", "omega", "scales",
                                 "opacities", "rgb"}
    assert (model.params["motion"] != 0).any() and (model.params["omega"] != 0).any()  # they were trained

    resumed = replace(cfg, out_dir=str(tmp_path / "resumed"))
    with pytest.raises(KeyboardInterrupt):  # dies at step 30, after the checkpoint at step 20
        train(resumed, tiny_scene, StopAt(30))
    assert torch.load(tmp_path / "resumed" / "checkpoint.pt", weights_only=False)["step"] == 20
    assert train(resumed, tiny_scene).status == "FINISHED"
    model2, _ = load_run(tmp_path / "resumed")
    assert all(torch.equal(model.params[k], model2.params[k]) for k in model.params)  # resumed to the same bits
