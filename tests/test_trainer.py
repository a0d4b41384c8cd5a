"""The training loop: it learns, is deterministic, resumes exactly, and records divergence."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch

from ftgspp.config import TrainConfig
from ftgspp.trainer import train


def small_cfg(path, out_dir, **kw) -> TrainConfig:
    cfg = TrainConfig()
    cfg.data.path = str(path)
    cfg.out_dir = str(out_dir)
    cfg.iterations = 40
    cfg.budget = 400
    cfg.backend = "cpu"
    cfg.progress = False
    cfg.log_every = 5
    cfg.checkpoint_every = 10
    cfg.sh_degree_interval = 10
    cfg.init.keyframe_stride = 3
    cfg.strategy.refine_every = 10
    cfg.strategy.refine_start_iter = 5
    cfg.strategy.refine_stop_iter = 35
    for k, v in kw.items():
        setattr(cfg, k, v)
    return cfg


def params(out_dir) -> dict[str, torch.Tensor]:
    return torch.load(out_dir / "gaussians.pt", weights_only=True)


def test_training_improves_over_initialisation(tiny_scene_dir, tiny_scene, tmp_path):
    before = train(small_cfg(tiny_scene_dir, tmp_path / "a", iterations=0), tiny_scene)
    after = train(small_cfg(tiny_scene_dir, tmp_path / "b", iterations=120), tiny_scene)
    assert after.status == "FINISHED"
    assert after.metrics["psnr"] > before.metrics["psnr"] + 3.0
    for key in ("psnr", "ssim1", "ssim2", "dssim1", "dssim2", "train_seconds", "iters_per_second",
                "peak_rss_mb", "n_gaussians"):
        assert key in after.metrics
    assert after.metrics["n_gaussians"] == 400
    saved = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert saved["psnr"] == pytest.approx(after.metrics["psnr"])
    assert list((tmp_path / "b" / "renders").glob("*.png"))
    # diagnostics run after evaluation; the synthetic scene has ground-truth motion
    assert (tmp_path / "b" / "diagnostics" / "lifetime_histogram.png").exists()
    assert "motion_epe_dynamic" in after.metrics and "lifetime_long_on_static" in after.metrics
    for score in ("lifetime_partition_contrast", "motion_role_switch", "flicker_static", "flicker_static_gt"):
        assert score in after.metrics, score  # the claims' ground-truth scores reach the tracker
    for phase in ("init_seconds", "eval_seconds", "eval_lpips_seconds", "diagnostics_seconds"):
        assert after.metrics[phase] >= 0.0, phase  # where the run's time went besides training


def test_same_seed_gives_bit_identical_parameters(tiny_scene_dir, tiny_scene, tmp_path):
    train(small_cfg(tiny_scene_dir, tmp_path / "a", seed=3), tiny_scene)
    train(small_cfg(tiny_scene_dir, tmp_path / "b", seed=3), tiny_scene)
    train(small_cfg(tiny_scene_dir, tmp_path / "c", seed=4), tiny_scene)
    a, b, c = params(tmp_path / "a"), params(tmp_path / "b"), params(tmp_path / "c")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not torch.equal(a["means"], c["means"])


class StopAt:
    """A tracker that crashes the run when a given step is logged."""

    def __init__(self, step):
        self.step = step

    def log_params(self, params):
        pass

    def log_metrics(self, metrics, step=None):
        if step == self.step:
            raise KeyboardInterrupt

    def log_artifact(self, path, artifact_path=None):
        pass

    def set_tags(self, tags):
        pass


def test_interrupted_run_resumes_to_the_same_result(tiny_scene_dir, tiny_scene, tmp_path):
    straight = tmp_path / "straight"
    train(small_cfg(tiny_scene_dir, straight), tiny_scene)
    resumed = tmp_path / "resumed"
    with pytest.raises(KeyboardInterrupt):  # dies at step 25, after the checkpoint at step 20
        train(small_cfg(tiny_scene_dir, resumed), tiny_scene, StopAt(25))
    assert torch.load(resumed / "checkpoint.pt", weights_only=False)["step"] == 20
    result = train(small_cfg(tiny_scene_dir, resumed), tiny_scene)
    assert result.status == "FINISHED"
    a, b = params(straight), params(resumed)
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_divergence_is_reported_not_raised(tiny_scene_dir, tiny_scene, tmp_path, monkeypatch):
    import ftgspp.trainer as trainer

    real = trainer.photometric

    def poisoned(pred, gt, w):
        loss, l1 = real(pred, gt, w)
        return loss * float("nan"), l1

    monkeypatch.setattr(trainer, "photometric", poisoned)
    result = train(small_cfg(tiny_scene_dir, tmp_path), tiny_scene)
    assert result.status == "FAILED" and result.failure == "diverged"
    assert result.metrics["diverged_at"] == 1.0 and result.metrics["train_seconds"] > 0


def test_color_correction_is_identity_at_start_and_absent_from_evaluation(tiny_scene_dir, tiny_scene, tmp_path):
    cfg = small_cfg(tiny_scene_dir, tmp_path / "cc", iterations=0)
    cfg.model.color_correction = True
    no_cc = train(small_cfg(tiny_scene_dir, tmp_path / "plain", iterations=0), tiny_scene)
    with_cc = train(cfg, tiny_scene)
    # at start the transforms are the identity, and evaluation never applies them
    assert with_cc.metrics["psnr"] == no_cc.metrics["psnr"]


def run_cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "harness.cli.ftgspp_cmd", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=600)


def test_cli_train_writes_metrics_and_prints_one_json_line(tiny_scene_dir, tmp_path):
    run_dir = tmp_path / "run"
    r = run_cli("train", "profile=smoke", f"data.path={tiny_scene_dir}", "backend=cpu", "progress=false",
                "init.keyframe_stride=3", f"hydra.run.dir={run_dir}", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    line = json.loads(r.stdout.strip().splitlines()[-1])
    assert line["status"] == "FINISHED" and "psnr" in line
    assert json.loads((run_dir / "metrics.json").read_text())["psnr"] == pytest.approx(line["psnr"])
    assert (run_dir / ".hydra" / "config.yaml").exists()
    init = json.loads((run_dir / "init.json").read_text())  # what the initial point set is made of
    assert init["init_points_total"] > 0 and 0 < init["init_real_share"] <= 1 and init["init_matcher_dense"] == 0
    assert init["init_velocity_points_scored"] > 0 and init["init_velocity_error_static"] >= 0  # ground truth


@pytest.mark.parametrize("args, words", [
    (["data.path=/nonexistent/scene"], ["/nonexistent/scene", "no such folder"]),
    (["iterations=abc", "data.path=X"], ["iterations", "could not be converted to Integer"]),
    (["strategy.relocation=teleport", "data.path=X"], ["strategy.relocation", "choose from mcmc, exact_copy"]),
    (["model.bogus=1", "data.path=X"], ["model.bogus: unknown key", "gate_gamma"]),  # the section's keys
    (["profile=quik", "data.path=X"], ["unknown profile", "choose from paper, quick, smoke"]),
])
def test_cli_bad_input_is_one_line_exit_2_and_writes_nothing(args, words, tiny_scene_dir, tmp_path):
    args = [a.replace("data.path=X", f"data.path={tiny_scene_dir}") for a in args]
    r = run_cli("train", *args, cwd=tmp_path)  # Hydra's default outputs/<date>/<time>
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and all(w in lines[0] for w in words) and "Traceback" not in r.stderr, lines
    assert not (tmp_path / "outputs").exists()  # a run that fails validation writes nothing


def test_cli_help_lists_the_config_groups_and_every_key_with_its_default(tmp_path):
    r = run_cli("train", "--help", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "ftgspp train [group=option ...]" in r.stdout
    assert "profile: paper, quick, smoke" in r.stdout and "model: ftgs, ftgspp" in r.stdout
    assert "keyframe_stride: 10" in r.stdout and "budget:" in r.stdout  # the keys with their defaults
    job = run_cli("train", "--cfg", "job", "model=ftgspp", cwd=tmp_path)
    assert job.returncode == 0 and "gate: true" in job.stdout
    assert not (tmp_path / "outputs").exists()


def test_lpips_training_loss_changes_the_optimisation(tiny_scene_dir, tiny_scene, tmp_path, lpips_weights):
    plain = train(small_cfg(tiny_scene_dir, tmp_path / "plain", iterations=10, diagnostics=False), tiny_scene)
    cfg = small_cfg(tiny_scene_dir, tmp_path / "lpips", iterations=10, diagnostics=False)
    cfg.loss.lpips = 0.01
    with_lpips = train(cfg, tiny_scene)
    assert plain.status == with_lpips.status == "FINISHED"
    a, b = params(tmp_path / "plain"), params(tmp_path / "lpips")
    assert not torch.equal(a["sh0"], b["sh0"])  # the perceptual term moved the colours differently
