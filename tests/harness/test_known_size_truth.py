"""Role switching against the truth on the known-size scene (``ground_truth: true``): the true
Gaussians, loaded as a trained model, score exactly the truth's level (excess 0, whatever order
they come in), and a model in which every moving Gaussian hands its object to another mid-clip
scores a clearly positive excess. The ground-truth files are checked against the true
Gaussians' own geometry (projected centres, velocities)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from ftgspp.config import DataConfig
from ftgspp.data.load import load_scene
from ftgspp.diagnostics.diagnose import ground_truth_scores
from ftgspp.diagnostics.lifetimes import lifetime_fractions
from ftgspp.diagnostics.motion import load_clean_frames, load_ground_truth
from ftgspp.diagnostics.truth import load_true_model, true_model
from ftgspp.methods.freetime import FreeTimeGaussians
from harness.run import known_size

TINY = dict(k=40, moving_share=0.5, n_cameras=4, n_frames=6, width=64, height=48, sigma_px=2.0, ground_truth=True)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return known_size.generate(tmp_path_factory.mktemp("ks_truth") / "scene", seed=5, **TINY)


def _scores(scene_dir: Path, model: FreeTimeGaussians) -> dict[str, float]:
    scene = load_scene(DataConfig(path=str(scene_dir), downsample=1))
    cam = scene.test_ids[0]
    gt = load_ground_truth(scene, cam)
    frac = lifetime_fractions(model, 0.05, scene.duration)
    return ground_truth_scores(model, scene, cam, gt, frac < 0.5, np.zeros((scene.n_frames, 48, 64, 3), np.float32),
                               backend="cpu", truth=load_true_model(scene), clean=load_clean_frames(scene, cam))


def test_the_ground_truth_files_follow_the_true_gaussians(scene_dir: Path) -> None:
    g = dict(np.load(scene_dir / "gt" / "gaussians.npz"))
    scene = load_scene(DataConfig(path=str(scene_dir), downsample=1))
    cam = scene.cameras[scene.test_ids[0]]
    gt = load_ground_truth(scene, scene.test_ids[0])
    assert gt.objects.dtype == np.uint16 and gt.objects.shape == (6, 48, 64)
    ids = np.unique(gt.objects[gt.objects > 0]) - 1
    assert len(ids) and (g["moving"][ids] > 0).all()  # only moving Gaussians label pixels
    # each labelled pixel lies within reach of its Gaussian's projected centre (3.5 sigma of its largest axis)
    hits = 0
    for f, t in enumerate(scene.times):
        centres = g["means"] + g["velocities"] * (t - float(g["t_mid"]))
        xc = centres @ cam.R.T + cam.T
        uv = (xc @ cam.K.T)[:, :2] / xc[:, 2:3]
        ys, xs = np.nonzero(gt.objects[f])
        i = gt.objects[f][ys, xs].astype(int) - 1
        reach = 3.5 * g["scales"].max(axis=1)[i] * cam.K[0, 0] / xc[i, 2]
        assert (np.hypot(xs - uv[i, 0], ys - uv[i, 1]) <= reach + 1.0).all()
        # where one moving Gaussian alone is seen (its own pixels, away from the others), the flow is its velocity
        own = np.linalg.norm(gt.flow3d[f][ys, xs] - g["velocities"][i], axis=1) < 1e-2
        hits += int(own.sum())
    assert hits > 0
    np.testing.assert_array_equal(load_clean_frames(scene, scene.test_ids[0]), scene.frames(scene.test_ids[0]))
    assert load_ground_truth(scene, scene.train_ids[0]) is None  # the held-out camera only


def test_the_true_gaussians_as_the_trained_model_score_the_truth_level(scene_dir: Path) -> None:
    g = dict(np.load(scene_dir / "gt" / "gaussians.npz"))
    perm = np.random.default_rng(0).permutation(len(g["means"]))  # another order of the same Gaussians
    shuffled = true_model({k: (v[perm] if np.ndim(v) else v) for k, v in g.items()})
    s = _scores(scene_dir, shuffled)
    assert s["motion_role_switch_gt"] >= 0 and s["motion_role_switch"] == pytest.approx(s["motion_role_switch_gt"],
                                                                                          abs=1e-6)
    assert abs(s["motion_role_switch_excess"]) < 1e-6


def test_a_model_that_hands_each_moving_object_over_mid_clip_scores_a_positive_excess(scene_dir: Path) -> None:
    """Every moving true Gaussian replaced by two copies of itself: one visible in the first half
    of the clip, one in the second (temporal centres at T/4 and 3T/4, temporal SD T/8). One
    hand-over per object in F frames moves the object's whole weight once: 1/(F − 1) of the
    mean per-frame distance at least."""
    g = dict(np.load(scene_dir / "gt" / "gaussians.npz"))
    scene = load_scene(DataConfig(path=str(scene_dir), downsample=1))
    truth = true_model(g)
    mov = torch.as_tensor(g["moving"] > 0)
    t0, T = float(scene.times[0]), float(scene.times[-1] - scene.times[0])
    p = {k: v.detach() for k, v in truth.params.items()}
    first = {k: v[mov].clone() for k, v in p.items()}
    second = {k: v[mov].clone() for k, v in p.items()}
    first["times"][:], second["times"][:] = t0 + T / 4, t0 + 3 * T / 4
    first["durations"][:] = second["durations"][:] = float(np.log(T / 8))
    params = {k: torch.cat([p[k][~mov], first[k], second[k]]) for k in p}
    handover = FreeTimeGaussians(params, truth.cfg)
    s = _scores(scene_dir, handover)
    F = scene.n_frames
    # clearly above the truth's level; the copies' opacities rise and fall (a Gaussian in time, not a
    # step), shifting weight against the still Gaussians they overlap too, so more than the bare 1/(F − 1)
    assert s["motion_role_switch_excess"] > 0.5 / (F - 1)
