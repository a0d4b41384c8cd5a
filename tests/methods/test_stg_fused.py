"""Spacetime Gaussians' fused stage (time evaluation + RGB colour + EWA projection) against
independent oracles.

Oracles: ``SpacetimeGaussians.at_time`` + ``project.project`` (the generic path, which the
``reference`` backend renders with) in float64 for the forward values; the same path
differentiated by PyTorch autograd, and by central finite differences in float64 (no autograd at
all), for the gradient of every parameter; the ``reference`` renderer end to end. The kernels are
float32 only, so every comparison is of float32 results against a float64 or float32 oracle, with
the tolerance stated where it is used. The Gaussians are of every awkward kind
(``awkward_scene``), with motion, rotation speed and finite lifetimes, evaluated off their
temporal centres, so every term of the hand-written chain rule through time is non-zero.
"""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from ftgspp.config import ModelConfig, TrainConfig
from ftgspp.data.scene import Camera
from ftgspp.methods.stg import SpacetimeGaussians
from ftgspp.methods.stg_fused import PARAM_NAMES, prepare
from ftgspp.render.contract import CameraTensors
from ftgspp.render.project import project
from ftgspp.trainer import train
from ftgspp.view import camera_tensors, render_view
from tests.methods.awkward_scene import H, W, awkward_gaussians, make_camera, render_both_backends
from tests.numba_threads import under_thread_counts

STG = ModelConfig(name="stg", method="stg", sh_degree=0, fused_stage=True)  # conf/model/stg.yaml
OUTPUTS = ("means2d", "conics", "colors", "opacities", "depths", "temporal", "means")
T_EVAL = 0.4


def make_model(seed: int) -> SpacetimeGaussians:
    """Awkward Gaussians that sit at ``awkward_gaussians``' positions at ``T_EVAL``, with cubic motion,
    rotation speed, temporal centres around it and temporal scales from 0.1 to 3 s (some fade to culling),
    colours outside [0, 1] (STGS composites them as given)."""
    g = torch.Generator().manual_seed(seed)
    world, log_scales = awkward_gaussians(g)
    n = world.shape[0]
    rand = lambda *shape: torch.rand(*shape, generator=g)  # noqa: E731
    randn = lambda *shape: torch.randn(*shape, generator=g)  # noqa: E731
    centre = rand(n)
    motion = 0.3 * randn(n, 9)
    dt = (T_EVAL - centre)[:, None]
    params = {
        "means": world - (motion[:, 0:3] * dt + motion[:, 3:6] * dt**2 + motion[:, 6:9] * dt**3),
        "trbf_center": centre,
        "trbf_scale": 0.8 * randn(n) - 0.7,
        "motion": motion,
        "quats": randn(n, 4) * (0.5 + rand(n, 1)),  # not unit
        "omega": 0.5 * randn(n, 4),
        "scales": log_scales,
        "opacities": 2 * randn(n),
        "rgb": 1.2 * rand(n, 3) - 0.1,
    }
    return SpacetimeGaussians({k: v.contiguous() for k, v in params.items()}, STG)


def as_dtype(model: SpacetimeGaussians, dtype: torch.dtype) -> SpacetimeGaussians:
    return SpacetimeGaussians({k: v.detach().to(dtype).clone() for k, v in model.params.items()}, STG)


def generic_path(model: SpacetimeGaussians, cam: Camera, t: float) -> dict[str, torch.Tensor]:
    """The oracle: at_time, its RGB, project (in the parameters' dtype: float64 parameters give the
    float64 oracle)."""
    dtype = model.params["means"].dtype
    viewmat, K, _ = (x.to(dtype) for x in camera_tensors(cam, "cpu"))
    g = model.at_time(t)
    means2d, conics, depths, radii, _ = project(g.means, g.quats, g.scales, viewmat, K, cam.width, cam.height,
                                                opacities=g.opacities)  # fmt: skip
    return dict(means2d=means2d, conics=conics, colors=g.colors, opacities=g.opacities, depths=depths, radii=radii,
                temporal=g.temporal, means=g.means)  # fmt: skip


def fused_path(model: SpacetimeGaussians, cam: Camera, t: float) -> dict[str, torch.Tensor]:
    return prepare(model.params, t, CameraTensors(*camera_tensors(cam, "cpu"), cam.width, cam.height))._asdict()


def cotangents(n: int, seed: int, dtype: torch.dtype = torch.float32) -> dict[str, torch.Tensor]:
    """Fixed random cotangents of the outputs (the loss is their inner product with the outputs)."""
    g = torch.Generator().manual_seed(100 + seed)
    shapes = dict(means2d=(n, 2), conics=(n, 3), colors=(n, 3), opacities=(n,), depths=(n,), temporal=(n,),
                  means=(n, 3))  # fmt: skip
    return {k: torch.randn(shapes[k], generator=g).to(dtype) for k in OUTPUTS}


def per_gaussian_loss(out: dict[str, torch.Tensor], w: dict[str, torch.Tensor]) -> torch.Tensor:
    """``[N]``: Gaussian i's share of sum_k <w_k, out_k> (each output row is one Gaussian's)."""
    return sum((w[k] * out[k]).reshape(out[k].shape[0], -1).sum(-1) for k in OUTPUTS)


def run(path, model: SpacetimeGaussians, cam: Camera, seed: int = 0):
    """Outputs and parameter gradients of <outputs, fixed random cotangents>."""
    for p in model.parameters():
        p.grad = None
    out = path(model, cam, T_EVAL)
    w = cotangents(len(model), seed, model.params["means"].dtype)
    per_gaussian_loss(out, w).sum().backward()
    grads = {k: (None if p.grad is None else p.grad.clone()) for k, p in model.params.items()}
    return {k: v.detach() for k, v in out.items()}, grads


def assert_grad_close(actual: torch.Tensor, expected: torch.Tensor, name: str, rel: float) -> None:
    """Every entry within rel * (|expected| + max |expected|) of the oracle."""
    expected = expected.to(actual.dtype)
    scale = expected.abs().max().item()
    err = (actual - expected).abs()
    worst = (err / (rel * (expected.abs() + scale) + 1e-12)).max().item()
    assert worst <= 1.0, f"{name}: max error {err.max().item():.3g} (scale {scale:.3g}, {worst:.2g} x tolerance)"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_matches_the_float64_generic_path(seed: int) -> None:
    model = make_model(seed)
    cam = make_camera()
    with torch.no_grad():
        out = fused_path(model, cam, T_EVAL)
        ref32 = generic_path(model, cam, T_EVAL)
        ref64 = generic_path(as_dtype(model, torch.float64), cam, T_EVAL)
    assert torch.equal(out["radii"], ref32["radii"].to(out["radii"].dtype))
    culled = (ref32["radii"] == 0).all(-1)
    assert culled.sum() >= 8 and (~culled).sum() >= 25  # both kinds present
    faded = ref64["temporal"] < 0.05
    assert faded.any() and (ref64["temporal"] > 0.9).any()  # the temporal RBF spans its range
    assert (ref64["colors"] < 0).any() and (ref64["colors"] > 1).any()  # RGB as given, not clamped
    # The float64 oracle, not the float32 one: float32 rounding of the conics of tiny Gaussians
    # (the low-pass dominates) depends on the CPU's vector code by up to 9e-5 relative
    # (test_freetime_fused.py); 1e-4 relative / 1e-5 absolute is a few float32 ulps of every output
    # here, and a wrong formula is off by O(1).
    for name in OUTPUTS:
        torch.testing.assert_close(out[name].double(), ref64[name], rtol=1e-4, atol=1e-5, msg=name)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_backward_matches_autograd_through_the_generic_path(seed: int) -> None:
    model = make_model(seed)
    cam = make_camera()
    _, grads = run(fused_path, model, cam, seed)
    _, ref32 = run(generic_path, as_dtype(model, torch.float32), cam, seed)
    _, ref64 = run(generic_path, as_dtype(model, torch.float64), cam, seed)
    for name in PARAM_NAMES:
        assert grads[name] is not None and grads[name].shape == model.params[name].shape, name
        assert ref64[name].abs().max() > 0, name  # every parameter takes part
        # 2e-4 of the largest entry (and of each entry): needles (det / (a c) ~ 1e-2) amplify float32
        # rounding in the kernel and in float32 autograd alike (test_freetime_fused.py); a wrong
        # derivative is off by O(1)
        assert_grad_close(grads[name], ref32[name], name, rel=2e-4)
        assert_grad_close(grads[name].double(), ref64[name], name, rel=2e-4)
    culled = (fused_path(model, cam, T_EVAL)["radii"] == 0).all(-1)
    for name in ("quats", "omega", "scales"):  # nothing reaches a culled Gaussian's shape
        assert (grads[name][culled] == 0).all(), name


def test_backward_matches_finite_differences_of_every_parameter() -> None:
    """Central differences of the float64 generic path (no autograd), for every entry of every
    parameter. Each Gaussian's outputs depend on its own parameters only, so moving one column of a
    parameter (say motion[:, 4]) for all Gaussians at once and reading each Gaussian's share of the
    loss gives that column's derivative for every Gaussian: two evaluations per column."""
    model = make_model(3)
    cam = make_camera()
    _, grads = run(fused_path, model, cam, 3)
    exact = as_dtype(model, torch.float64)
    w = cotangents(len(model), 3, torch.float64)
    with torch.no_grad():
        culled = (generic_path(exact, cam, T_EVAL)["radii"] == 0).all(-1)
    h = 1e-6
    checked = 0
    for name in PARAM_NAMES:
        p = exact.params[name].data
        flat = p.view(p.shape[0], -1)
        fd = torch.empty_like(flat)
        for c in range(flat.shape[1]):
            losses = []
            for step in (h, -h):
                flat[:, c] += step
                with torch.no_grad():
                    out = generic_path(exact, cam, T_EVAL)
                    losses.append(per_gaussian_loss(out, w))  # before the step is undone: colors is rgb itself
                flat[:, c] -= step
                assert torch.equal((out["radii"] == 0).all(-1), culled), f"{name}[:, {c}]: a step changed the culling"
            fd[:, c] = (losses[0] - losses[1]) / (2 * h)
            checked += flat.shape[0]
        # h = 1e-6 in float64: truncation O(h^2 f''') and rounding O(1e-16 / h) are both far below the
        # float32 kernel's own error, so the tolerance is the autograd test's
        assert_grad_close(grads[name].double(), fd.view(p.shape), name, rel=2e-4)
    assert checked == sum(p.numel() for p in model.params.values())


def test_bitwise_deterministic_across_runs_and_thread_counts() -> None:
    model = make_model(5)
    cam = make_camera()
    results = under_thread_counts(lambda: run(fused_path, model, cam, 5))
    out0, grads0 = results[0]
    for out, grads in results[1:]:
        assert all(torch.equal(out0[k], out[k]) for k in out0)
        assert all(torch.equal(grads0[k], grads[k]) for k in PARAM_NAMES)


def test_render_view_cpu_matches_reference_end_to_end() -> None:
    """The cpu backend through the hook (fused node + Numba rasterizer) vs the reference backend
    (generic path, autograd): image, alpha, depth, radii, the Gaussians at t, every parameter's
    gradient and the screen-space gradient the relocation statistics read."""
    results = render_both_backends(lambda: make_model(7), T_EVAL, 0)
    assert results["cpu"][0].stage == "fused" and results["reference"][0].stage == "generic"  # the hook rendered
    (out, g, grads), (ref, ref_g, ref_grads) = results["cpu"], results["reference"]
    assert out.image.shape == (H, W, 3)
    # the two rasterizers composite in float32 in different orders: 1e-5 is a few ulps of a pixel
    torch.testing.assert_close(out.image, ref.image, rtol=0, atol=1e-5)
    torch.testing.assert_close(out.alpha, ref.alpha, rtol=0, atol=1e-5)
    torch.testing.assert_close(out.depth, ref.depth, rtol=1e-5, atol=1e-5)
    assert torch.equal(out.radii.int(), ref.radii.int())
    for name in ("means", "quats", "opacities", "temporal", "colors", "log_scales"):
        torch.testing.assert_close(getattr(g, name), getattr(ref_g, name), msg=name)
    assert (ref.alpha > 0.3).any()  # something is drawn
    for name, expected in ref_grads.items():
        assert expected is not None and expected.abs().max() > 0, name
        assert_grad_close(grads[name], expected, name, rel=1e-4)


def test_a_subclass_that_redefines_the_formulas_renders_through_at_time() -> None:
    """The kernel knows STGS's formulas only: a subclass with another temporal opacity gets no fused
    stage and the cpu backend renders its ``at_time``."""

    class Flat(SpacetimeGaussians):
        def temporal_opacity(self, t):
            return torch.ones_like(self.params["opacities"])

    cam = make_camera()
    camera = CameraTensors(*camera_tensors(cam, "cpu"), cam.width, cam.height)
    base = make_model(8)
    flat = Flat({k: v.detach().clone() for k, v in base.params.items()}, STG)
    assert base.prepare_cpu(T_EVAL, camera, 0) is not None and flat.prepare_cpu(T_EVAL, camera, 0) is None
    cpu, g = render_view(flat, cam, T_EVAL, 0, backend="cpu")
    ref, _ = render_view(flat, cam, T_EVAL, 0, backend="reference")
    assert bool((g.temporal == 1).all())
    torch.testing.assert_close(cpu.image, ref.image, rtol=0, atol=1e-5)


def test_parameter_edited_before_backward_raises() -> None:
    model = make_model(4)
    out = fused_path(model, make_camera(), T_EVAL)
    with torch.no_grad():
        model.params["motion"].add_(0.1)  # e.g. an optimizer step between forward and backward
    with pytest.raises(RuntimeError, match="inplace"):
        out["means2d"].sum().backward()


class Params:
    """A tracker that keeps the params the trainer logs (``render_stage``: which path rendered)."""

    def __init__(self) -> None:
        self.params: dict[str, str] = {}

    def log_params(self, params):
        self.params.update({k: str(v) for k, v in params.items()})

    def log_metrics(self, metrics, step=None):
        pass

    def log_artifact(self, path, artifact_path=None):
        pass

    def set_tags(self, tags):
        pass


@pytest.mark.slow
def test_training_through_the_fused_stage_is_seeded_and_close_to_the_generic_path(tiny_scene, tmp_path,
                                                                                 monkeypatch) -> None:
    """Seeded trainings through the fused stage give the same bits twice; a training through the
    generic path (the hook switched off: STGS before it had one) gives close metrics, not the same bits:
    the kernel and autograd round exp and sum the chain rule in other orders, and the float32 differences
    grow over training (at 200 iterations: 4e-4 dB of PSNR apart, where seeds 3, 4, 5 spread 0.13 dB). The
    run records which path rendered (param ``render_stage``)."""
    from ftgspp.methods import stg_fused
    from ftgspp.methods.base import DynamicGaussians

    calls = []
    real = stg_fused.prepare
    monkeypatch.setattr(stg_fused, "prepare", lambda *a, **k: calls.append(1) or real(*a, **k))
    cfg = TrainConfig(model=STG, profile="smoke", iterations=40, budget=300, backend="cpu", seed=3,
                      eval_lpips=[], diagnostics=False, progress=False, checkpoint_every=10**9)  # fmt: skip
    cfg.strategy.refine_every, cfg.strategy.refine_start_iter, cfg.strategy.refine_stop_iter = 10, 5, 35
    cfg.init.max_features = 500
    params, metrics, stages = {}, {}, {}
    for name, seed in (("a", 3), ("b", 3), ("c", 4), ("generic", 3)):
        if name == "generic":
            monkeypatch.setattr(SpacetimeGaussians, "prepare_cpu", DynamicGaussians.prepare_cpu)
        tracker = Params()
        result = train(replace(cfg, seed=seed, out_dir=str(tmp_path / name)), tiny_scene, tracker)
        assert result.status == "FINISHED"
        params[name] = torch.load(tmp_path / name / "gaussians.pt", weights_only=True)
        metrics[name], stages[name] = result.metrics, tracker.params["render_stage"]
    assert len(calls) >= 3 * 40  # every training iteration of a, b, c (and their evaluation) rendered through it
    assert stages == {"a": "fused", "b": "fused", "c": "fused", "generic": "generic"}
    a, b, c = params["a"], params["b"], params["c"]
    assert set(a) == set(PARAM_NAMES)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(a["means"], c["means"])
    assert (a["motion"] != 0).any() and (a["omega"] != 0).any()  # the time parameters trained
    # 0.02 dB and 2e-3 SSIM: 40x the gap measured at 200 iterations, a sixth of the seed-to-seed spread
    assert abs(metrics["a"]["psnr"] - metrics["generic"]["psnr"]) < 0.02
    assert abs(metrics["a"]["ssim1"] - metrics["generic"]["ssim1"]) < 2e-3
    for k in a:  # the same Gaussians, moved alike
        torch.testing.assert_close(a[k], params["generic"][k], rtol=0.05, atol=0.05, msg=k)


def test_the_fused_stage_is_part_of_the_configuration_so_earlier_runs_keep_their_bits() -> None:
    """STGS's fused stage agrees with its generic path to rounding, not bit for bit, so it is an
    option (``model.fused_stage``): conf/model/stg.yaml turns it on (a new config hash for STGS's
    runs), while an STGS config without it, and every FreeTimeGS config, keep their path and hash."""
    from harness.spec.confighash import config_hash, flatten_config
    from harness.spec.schema import compose, to_train_config

    cam = make_camera()
    camera = CameraTensors(*camera_tensors(cam, "cpu"), cam.width, cam.height)
    base = make_model(8)
    before = {k: v.detach().clone() for k, v in base.params.items()}
    assert SpacetimeGaussians(before, replace(STG, fused_stage=None)).prepare_cpu(T_EVAL, camera, 0) is None
    assert SpacetimeGaussians(before, replace(STG, fused_stage=False)).prepare_cpu(T_EVAL, camera, 0) is None
    assert SpacetimeGaussians(before, STG).prepare_cpu(T_EVAL, camera, 0) is not None
    stg, stg_old, ftgs = (to_train_config(compose(o)) for o in (
        ["profile=quick", "model=stg"], ["profile=quick", "model=stg", "model.fused_stage=null"], ["profile=quick"]))
    assert stg.model.fused_stage is True and stg_old.model.fused_stage is None and ftgs.model.fused_stage is None
    h = {name: config_hash(flatten_config(c)) for name, c in (("stg", stg), ("stg_old", stg_old), ("ftgs", ftgs))}
    assert h["stg"] != h["stg_old"]
    ftgs_flat = flatten_config(ftgs)
    assert config_hash(ftgs_flat) == config_hash({k: v for k, v in ftgs_flat.items() if k != "model.fused_stage"})
