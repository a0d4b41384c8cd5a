"""Pruning by spatio-temporal significance: it keeps what the views need, its scores are the
renderer's blending weights (against a pixel-by-pixel oracle), and ``ftgspp prune`` runs end to end."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from ftgspp.checkpoint import load_run
from ftgspp.config import InitConfig, ModelConfig, TrainConfig
from ftgspp.data.scene import Camera, Scene
from ftgspp.methods.freetime import FreeTimeGaussians, duration_to_param
from ftgspp.pruning import keep_top, kept_count, prune_run, recovery_config, significance, view_significance
from ftgspp.render.project import project
from ftgspp.strategy import Relocator
from ftgspp.train_state import set_learning_rates
from ftgspp.trainer import train
from ftgspp.view import render_view
from harness.cli import ftgspp_cmd
from tests.render.test_reference import brute_force

W, H, FOCAL, FPS = 32, 24, 30.0, 10.0


def camera(name: str, x: float, backwards: bool = False) -> Camera:
    """Looking down +z from (x, 0, 0), or down -z from (x, 0, 10) when ``backwards``."""
    K = np.array([[FOCAL, 0, (W - 1) / 2], [0, FOCAL, (H - 1) / 2], [0, 0, 1.0]])
    R = np.diag([-1.0, 1.0, -1.0]) if backwards else np.eye(3)
    centre = np.array([x, 0.0, 10.0 if backwards else 0.0])
    return Camera(name, K, R, -R @ centre, W, H)


def scene_of(cameras: list[Camera], n_frames: int = 4) -> Scene:
    """Every camera but the last trains; frames at 0, 0.1, ... s (no images: scores need none)."""
    return Scene(name="planted", root=None, cameras=cameras, frame_ids=np.arange(n_frames), fps=FPS,
                 train_ids=list(range(len(cameras) - 1)), test_ids=[len(cameras) - 1],
                 decode=lambda i: np.zeros((n_frames, H, W, 3), np.uint8))  # fmt: skip


def grid(half_x: float, half_y: float, z: float, step: float) -> np.ndarray:
    xs, ys = np.arange(-half_x, half_x + 1e-9, step), np.arange(-half_y, half_y + 1e-9, step)
    X, Y = np.meshgrid(xs, ys)
    return np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], axis=1)


def planted_model() -> tuple[FreeTimeGaussians, np.ndarray, dict[str, np.ndarray]]:
    """Needed: an opaque occluder (a stack of 8 large Gaussians at depth 3, opaque within ~5 px of
    its axis) and a sparse backdrop around it at depth 6. Redundant: small copies hidden behind the
    occluder's core, Gaussians outside every training view (beside it, behind the cameras), and
    Gaussians in front of everything that live only 5 s after the clip."""
    stack = np.c_[np.zeros((8, 2)), 3.0 + 0.01 * np.arange(8)]
    backdrop = grid(2.6, 1.8, 6.0, 0.4)
    backdrop = backdrop[np.hypot(backdrop[:, 0], backdrop[:, 1]) > 2.0]  # clear of the occluder's core
    hidden = grid(0.2, 0.2, 5.0, 0.1)  # within ~1 px of the axis at depth 5
    outside = np.array([[40.0, 0, 4], [-40, 0, 4], [0, 30, 4], [0, 0, -3], [0.2, 0.1, -1]])
    late = grid(0.6, 0.4, 2.0, 0.2)  # in front of everything, alive only around t = 5 s
    parts = {"stack": stack, "backdrop": backdrop, "hidden": hidden, "outside": outside, "late": late}
    sizes = {"stack": 0.6, "backdrop": 0.08, "hidden": 0.03, "outside": 0.1, "late": 0.05}
    means = np.concatenate(list(parts.values()))
    spacing = np.concatenate([np.full(len(v), sizes[k]) for k, v in parts.items()])
    n = len(means)
    cfg, init = ModelConfig(sh_degree=0), InitConfig(opacity=0.99, duration=1e3, scale_factor=1.0)
    model = FreeTimeGaussians.from_points(means, np.full((n, 3), 0.5), np.zeros(n), np.zeros((n, 3)), spacing,
                                          cfg, init)  # fmt: skip
    bounds = np.cumsum([0] + [len(p) for p in parts.values()])
    where = {k: np.arange(bounds[i], bounds[i + 1]) for i, k in enumerate(parts)}
    with torch.no_grad():
        model.params["times"][where["late"]] = 5.0
        model.params["durations"][where["late"]] = duration_to_param(0.2, None)
    needed = np.zeros(n, bool)
    needed[np.r_[where["stack"], where["backdrop"]]] = True
    return model, needed, where


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_pruning_keeps_the_gaussians_the_views_need(backend):
    model, needed, where = planted_model()
    # the held-out camera (last) looks from behind, where the hidden copies are in front: it must not count
    scene = scene_of([camera("a", 0.0), camera("b", 0.3), camera("held_out", 0.0, backwards=True)])
    scores = significance(model, scene, backend)
    assert (scores[torch.from_numpy(needed)] > 0).all()
    for kind in ("hidden", "outside", "late"):
        assert (scores[where[kind]] == 0).all(), kind
    keep = keep_top(scores, needed.mean())
    assert keep.numpy().tolist() == needed.tolist()
    # what the scores leave out would count elsewhere: at t = 5 s, and seen from behind
    assert (significance(model, replace(scene, frame_ids=np.array([50])), backend)[where["late"]] > 0).all()
    behind = replace(scene, train_ids=[2])
    assert (significance(model, behind, backend)[where["hidden"]] > 0).all()


def test_ties_keep_the_lower_index_and_the_count_rounds_up():
    scores = torch.tensor([0.0, 2.0, 0.0, 2.0, 1.0], dtype=torch.float64)
    assert keep_top(scores, 0.4).nonzero().flatten().tolist() == [1, 3]
    assert keep_top(scores, 0.6).nonzero().flatten().tolist() == [1, 3, 4]
    assert keep_top(scores, 0.8).nonzero().flatten().tolist() == [0, 1, 3, 4]  # of the tied zeros, index 0
    assert keep_top(scores, 1.0).all()
    assert [kept_count(10, f) for f in (0.3, 0.31, 0.01, 1.0)] == [3, 4, 1, 10]
    for bad in (0.0, -0.5, 1.5, math.nan):
        with pytest.raises(Exception, match="--keep"):
            kept_count(10, bad)


def random_model(seed: int, n: int = 24) -> FreeTimeGaussians:
    """Overlapping Gaussians in front of the cameras, moving, with lifetimes inside the clip."""
    rng = np.random.default_rng(seed)
    means = np.c_[rng.uniform(-1.0, 1.0, n), rng.uniform(-0.7, 0.7, n), rng.uniform(3.0, 6.0, n)]
    cfg = ModelConfig(sh_degree=0)
    model = FreeTimeGaussians.from_points(means, rng.uniform(size=(n, 3)), rng.uniform(0, 0.3, n),
                                          rng.normal(0, 0.5, (n, 3)), rng.uniform(0.05, 0.3, n), cfg,
                                          InitConfig(opacity=0.5, duration=0.15))  # fmt: skip
    with torch.no_grad():
        model.params["opacities"].copy_(torch.from_numpy(rng.normal(1.0, 1.5, n)))
        model.params["scales"].add_(torch.from_numpy(rng.normal(0, 0.3, (n, 3))))
        q = torch.from_numpy(rng.normal(size=(n, 4)))
        model.params["quats"].copy_(q / q.norm(dim=-1, keepdim=True))
    return model


def oracle_significance(model: FreeTimeGaussians, scene: Scene) -> tuple[np.ndarray, float]:
    """Σ over training views and pixels of each Gaussian's α T, by the contract's pixel-by-pixel
    loop (tests/render/test_reference.py) in float64: one-hot colours composite each Gaussian's
    weight into its own channel. Returns the scores and the smallest threshold margin."""
    m64 = FreeTimeGaussians({k: v.detach().double() for k, v in model.params.items()}, model.cfg)
    n = len(m64)
    total, margin = np.zeros(n), math.inf
    for cam_idx in scene.train_ids:
        cam = scene.cameras[cam_idx]
        for t in scene.times:
            g = m64.at_time(float(t))
            viewmat, K = torch.from_numpy(cam.viewmat), torch.from_numpy(cam.K)
            means2d, conics, depths, radii, _ = project(g.means, g.quats, g.scales, viewmat, K, W, H,
                                                        opacities=g.opacities)  # fmt: skip
            image, _, _, m = brute_force(means2d, conics, torch.eye(n, dtype=torch.float64), g.opacities, depths,
                                         radii, W, H)  # fmt: skip
            total += image.sum(dim=(0, 1)).numpy()
            margin = min(margin, m)
    return total, margin


@pytest.mark.parametrize("seed", [0, 1])
def test_scores_match_a_pixel_by_pixel_oracle(seed):
    model = random_model(seed)
    scene = scene_of([camera("a", 0.0), camera("b", 0.4), camera("held_out", -0.4)], n_frames=3)
    want, margin = oracle_significance(model, scene)
    assert margin > 1e-4  # no decision of the oracle is within float32 rounding of its threshold
    assert (want > 0).sum() >= 12  # most Gaussians are seen, with a spread of weights
    for backend in ("cpu", "reference"):
        got = significance(model, scene, backend).numpy()
        np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-4 * want.max(), err_msg=backend)


def test_a_views_scores_sum_to_its_rendered_alpha():
    model = random_model(2)
    cam = camera("a", 0.1)
    with torch.no_grad():
        out, _ = render_view(model, cam, 0.1, 0, backend="cpu")
    w = view_significance(model, cam, 0.1, backend="cpu")
    assert float(w.sum()) == pytest.approx(float(out.alpha.sum()), rel=1e-5)
    assert all(p.grad is None for p in model.params.values())  # scoring leaves no parameter gradients


def test_recovery_continues_the_runs_schedule_without_relocation(tmp_path):
    cfg = TrainConfig(iterations=200)
    rcfg = recovery_config(cfg, 20, tmp_path)
    assert rcfg.iterations == 220 and rcfg.out_dir == str(tmp_path) and cfg.iterations == 200
    p = torch.nn.Parameter(torch.zeros(1))
    opt = torch.optim.Adam([{"params": [p], "lr": 1.0, "initial_lr": 1.0, "decays": True}])

    def rate(c: TrainConfig, step: int) -> float:
        set_learning_rates(opt, step, c)
        return opt.param_groups[0]["lr"]

    for step in (0, 100, 199):
        assert rate(rcfg, step) == pytest.approx(rate(cfg, step), rel=1e-9)
    assert rate(rcfg, 219) == pytest.approx(cfg.lr.means_final_ratio ** (219 / 200), rel=1e-9)
    cfg2 = TrainConfig(iterations=200)
    cfg2.strategy.refine_stop_iter = 10_000  # relocation would run on past the run's end
    assert not any(Relocator(recovery_config(cfg2, 20, tmp_path).strategy).due(s) for s in range(201, 221))


# --------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def tiny_run(tiny_scene_dir, tiny_scene, tmp_path_factory, lpips_weights):
    """A smoke-sized FreeTimeGS++ run with colour correction (30 iterations, 300 Gaussians)."""
    cfg = TrainConfig(iterations=30, budget=300, backend="cpu", progress=False, log_every=10, checkpoint_every=20,
                      sh_degree_interval=10, diagnostics=False, eval_lpips=["alex"])  # fmt: skip
    cfg.data.path = str(tiny_scene_dir)
    cfg.out_dir = str(tmp_path_factory.mktemp("runs") / "run")
    cfg.init.keyframe_stride = 3
    cfg.strategy.refine_every, cfg.strategy.refine_start_iter, cfg.strategy.refine_stop_iter = 10, 5, 25
    cfg.model.color_correction = True
    assert train(cfg, tiny_scene).status == "FINISHED"
    return cfg.out_dir


def test_cli_prunes_recovers_evaluates_and_writes_a_loadable_run(tiny_run, tmp_path, capsys):
    out = tmp_path / "pruned"
    assert ftgspp_cmd.main(["prune", tiny_run, "--keep", "0.4", "--recover", "6", "--out", str(out)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"pruned {tiny_run}: 300 -> 120 Gaussians"), lines
    res = json.loads((out / "prune.json").read_text())
    assert res["n_before"] == 300 and res["n_after"] == 120 and res["recover_iterations"] == 6
    for key in ("psnr", "psnr_cc", "ssim1", "lpips_alex"):
        assert math.isfinite(res["metrics"][key]) and key in res["original"], key
    assert res["metrics"]["n_gaussians"] == 120 and math.isfinite(res["before_recovery"]["psnr"])
    assert 0.4 < res["kept_significance_share"] <= 1
    # the output is a run: the kept Gaussians, fine-tuned, and the colour correction the run learned
    pruned, cfg = load_run(out)
    assert len(pruned) == 120 and cfg.out_dir == str(out)
    assert (out / "color_correction.npy").is_file() and (out / "metrics.json").is_file()
    scores = torch.from_numpy(np.load(out / "significance.npy"))
    original, _ = load_run(tiny_run)
    kept = original.subset(keep_top(scores, 0.4))
    moved = (pruned.params["means"] - kept.params["means"]).abs().max()
    assert 0 < moved < 0.5  # the same Gaussians, moved by the recovery fine-tune


def test_no_recovery_writes_exactly_the_kept_gaussians(tiny_run, tmp_path):
    res = prune_run(tiny_run, 0.25, 0, out_dir=tmp_path / "p0")
    assert res["n_after"] == 75 and res["seconds"]["recovery"] == 0.0
    original, _ = load_run(tiny_run)
    keep = keep_top(torch.from_numpy(np.load(tmp_path / "p0" / "significance.npy")), 0.25)
    pruned, _ = load_run(tmp_path / "p0")
    for name, p in pruned.params.items():
        assert torch.equal(p, original.params[name][keep]), name
    assert res["metrics"]["psnr"] == res["before_recovery"]["psnr"]  # the same model, scored twice


@pytest.mark.parametrize("args, words", [
    (["--keep", "0"], ["--keep", "must be in (0, 1]"]),
    (["--keep", "1.5"], ["--keep", "must be in (0, 1]"]),
    (["--keep", "half"], ["--keep", "not a number"]),
    (["--keep", "0.5", "--recover", "-3"], ["--recover", "must be >= 0"]),
    (["--recover", "3"], ["--keep", "required"]),
])
def test_cli_bad_input_is_one_line_exit_2_and_writes_nothing(tiny_run, tmp_path, monkeypatch, capsys, args, words):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        ftgspp_cmd.main(["prune", tiny_run, *args])
    err = capsys.readouterr().err
    assert exit_.value.code == 2, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and all(w in lines[0] for w in words), lines
    assert not (Path(tiny_run) / "pruned").exists() and not list(tmp_path.iterdir())


def test_cli_no_such_run_is_one_line_exit_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "harness.cli.ftgspp_cmd", "prune", str(tmp_path / "nowhere"), "--keep",
                        "0.5"], cwd=tmp_path, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert r.returncode == 2 and r.stderr.strip() == f"error: {tmp_path / 'nowhere'}: no such run folder", r.stderr
