"""``init.matcher=known``: the control starts from a known-size scene's true Gaussians, perturbed as stated."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from ftgspp.config import DataConfig, InitConfig, ModelConfig, TrainConfig
from ftgspp.data.load import load_scene
from ftgspp.errors import InputError
from ftgspp.image_metrics import psnr
from ftgspp.init import initialize
from ftgspp.init.known import COLOUR_JITTER, POSITION_JITTER
from ftgspp.train_state import build_model
from ftgspp.view import render_view
from harness.run.known_size import generate

K = 120
CFG = InitConfig(matcher="known")


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate(tmp_path_factory.mktemp("known") / "scene", seed=2, k=K, n_cameras=4, n_frames=4, width=64,
                    height=48, sigma_px=2.0)


def test_the_points_are_the_truth_perturbed_as_stated(scene_dir: Path) -> None:
    truth = np.load(scene_dir / "known_size.npz")
    scene = load_scene(DataConfig(path=str(scene_dir), downsample=1))
    pts = initialize(scene, CFG, K, seed=0)
    assert len(pts) == K and pts.stats["init_points_total"] == K
    scale = truth["scales"].mean(axis=1)
    np.testing.assert_array_equal(pts.velocities, truth["velocities"].astype(np.float32))
    np.testing.assert_allclose(pts.times, float(truth["t_mid"]))
    np.testing.assert_allclose(pts.spacing * CFG.scale_factor, scale, rtol=1e-6)  # the model's initial scale
    offsets = (pts.means - truth["means"]) / scale[:, None]  # in units of each Gaussian's own scale
    assert abs(offsets.mean()) < 0.1 and offsets.std() == pytest.approx(POSITION_JITTER, rel=0.12)
    colour = pts.colors - truth["colors"]
    inside = (pts.colors > 0) & (pts.colors < 1)  # not clipped
    assert colour[inside].std() == pytest.approx(COLOUR_JITTER, rel=0.12)
    again, other = initialize(scene, CFG, K, seed=0), initialize(scene, CFG, K, seed=1)
    assert np.array_equal(again.means, pts.means) and not np.allclose(other.means, pts.means)


def test_other_budgets_are_fitted_like_matched_points(scene_dir: Path) -> None:
    scene = load_scene(DataConfig(path=str(scene_dir), downsample=1))
    more, fewer = initialize(scene, CFG, K + 30, seed=0), initialize(scene, CFG, K // 2, seed=0)
    assert len(more) == K + 30 and len(fewer) == K // 2
    truth = np.load(scene_dir / "known_size.npz")
    assert {tuple(v) for v in fewer.velocities} <= {tuple(v) for v in truth["velocities"].astype(np.float32)}


def test_the_trainer_starts_from_them_and_a_scene_without_truth_is_refused(scene_dir: Path, tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """Built through the trainer's own ``build_model``, the control's first model draws the
    held-out view better than the same Gaussians with their centres shuffled among them, and
    better still without the stated perturbation."""
    from ftgspp.init import known

    cfg = TrainConfig(data=DataConfig(path=str(scene_dir), downsample=1), model=ModelConfig(sh_degree=0),
                      init=replace(CFG, duration=10.0, opacity=0.85), budget=K, backend="cpu")
    scene = load_scene(cfg.data)
    cam, t = scene.cameras[scene.test_ids[0]], float(scene.times[1])
    gt = torch.from_numpy(scene.image(scene.test_ids[0], 1))

    def score(m) -> float:
        with torch.no_grad():
            out, _ = render_view(m, cam, t, 0, torch.zeros(3), "cpu")
        return float(psnr(out.image.clamp(0, 1), gt))

    model = build_model(cfg, scene, torch.device("cpu"))
    np.testing.assert_array_equal(model.params["means"].detach().numpy(), initialize(scene, cfg.init, K, cfg.seed).means)
    start = score(model)
    with torch.no_grad():
        model.params["means"].copy_(model.params["means"][torch.randperm(K, generator=torch.Generator().manual_seed(0))])
    shuffled = score(model)
    monkeypatch.setattr(known, "POSITION_JITTER", 0.0)
    monkeypatch.setattr(known, "COLOUR_JITTER", 0.0)
    exact = score(build_model(cfg, scene, torch.device("cpu")))
    print(f"held-out PSNR of the starting model: {start:.2f} dB; centres shuffled {shuffled:.2f}; unperturbed {exact:.2f}")
    assert exact > start > shuffled + 3.0
    with pytest.raises(InputError, match="known_size.npz"):
        initialize(replace(scene, root=tmp_path), CFG, K, seed=0)
