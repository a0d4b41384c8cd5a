"""Ground-truth scores of the secrets on tiny constructed renders with known answers:
per-Gaussian mask weights (against the rendered alpha), the lifetime partition contrast and
the lifetime histogram's dip test (secret 1, against the ``diptest`` package and a simulated
null), role switching (secret 2) and static-background flicker against a noise-free
reference (secret 4)."""

from __future__ import annotations

import diptest
import numpy as np
import pytest
import torch
from test_diagnostics import FPS, camera, object_masks, tiny_scene, wall_and_object

from ftgspp.config import TrainConfig
from ftgspp.diagnostics.diagnose import run_diagnostics
from ftgspp.diagnostics.lifetimes import (
    dip_critical_value,
    drawn_in_clip,
    lifetime_dip,
    lifetime_fractions,
    mask_weights,
    partition_scores,
    role_switch_score,
)
from ftgspp.diagnostics.motion import composite, static_flicker
from ftgspp.methods.freetime import duration_to_param


def test_partition_scores_by_hand():
    short = np.array([True, True, False, False])
    w_dyn = np.array([3.0, 1.0, 0.0, 0.0])  # moving pixels: only short-lived Gaussians
    w_sta = np.array([0.0, 0.0, 5.0, 5.0])  # static pixels: only long-lived ones
    assert partition_scores(w_dyn, w_sta, short) == {"short_share_dynamic": 1.0, "short_share_static": 0.0,
                                                     "partition_contrast": 1.0}
    mixed = partition_scores(np.array([1.0, 0.0, 3.0, 0.0]), np.array([1.0, 1.0, 1.0, 1.0]), short)
    assert mixed["short_share_dynamic"] == 0.25 and mixed["short_share_static"] == 0.5
    assert mixed["partition_contrast"] == pytest.approx(-0.25)
    assert np.isnan(partition_scores(np.zeros(4), np.ones(4), short)["partition_contrast"])


def test_role_switch_score_by_hand():
    same = np.tile([1.0, 2.0, 1.0, 0.0], (5, 1))
    assert role_switch_score(same) == 0.0
    assert role_switch_score(3 * same) == 0.0  # only proportions count, not the object's rendered size
    disjoint = np.eye(4)  # a new Gaussian every frame
    assert role_switch_score(disjoint) == 1.0
    half = np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 1.0]])  # one of two Gaussians handed over
    assert role_switch_score(half) == pytest.approx(0.5)
    assert role_switch_score(np.array([[1.0, 0.0], [0.0, 0.0], [1.0, 0.0]])) == 0.0  # an empty frame is skipped


def test_static_flicker_on_a_constructed_clip():
    rng = np.random.default_rng(0)
    f, h, w = 6, 5, 7
    frames = np.broadcast_to(rng.uniform(size=(1, h, w, 3)), (f, h, w, 3)).copy()
    objects = np.zeros((f, h, w), np.uint8)
    frames[:, 0, 0] += np.array([0.1, -0.1] * 3)[:, None]  # one static pixel flickers by +-0.1
    frames[:, 4] = rng.uniform(size=(f, w, 3))  # the bottom row holds a moving object...
    objects[2, 4] = 1  # ...marked in one frame only: excluded for the whole clip
    res = static_flicker(frames, objects)
    assert res["n_static_px"] == 4 * 7
    assert res["flicker"] == pytest.approx(0.1 / 28)  # std 0.1 on one pixel, 0 on 27 others
    assert static_flicker(frames[:, :4], objects[:, :4])["flicker"] == pytest.approx(0.1 / 28)


def test_mask_weights_sum_to_rendered_alpha_and_follow_the_object():
    model, is_obj = wall_and_object()
    cam = camera()
    inside, edge = object_masks(cam, 0.0)
    obj = inside.astype(bool) & ~edge
    static = ~inside.astype(bool) & ~edge
    w = mask_weights(model, cam, 0.0, np.stack([obj, static]))
    assert w.shape == (len(is_obj), 2) and (w >= -1e-9).all()
    _, alpha = composite(model, cam, 0.0, model.params["velocities"].detach())
    np.testing.assert_allclose(w.sum(axis=0), [alpha[obj].sum(), alpha[static].sum()], rtol=1e-4)
    assert w[is_obj, 0].sum() / w[:, 0].sum() > 0.999  # object pixels: rendered by the object's Gaussians
    assert w[~is_obj, 1].sum() / w[:, 1].sum() > 0.999  # static pixels: by the wall
    # the object's Gaussians as the short-lived group: a perfect partition
    assert partition_scores(w[:, 0], w[:, 1], is_obj)["partition_contrast"] > 0.998


def test_a_rigidly_moving_object_keeps_its_gaussians():
    model, is_obj = wall_and_object()
    cam = camera()
    per_frame = []
    for t in np.linspace(0.0, 0.6, 4):
        inside, edge = object_masks(cam, float(t))
        per_frame.append(mask_weights(model, cam, float(t), (inside.astype(bool) & ~edge)[None])[:, 0])
    weights = np.stack(per_frame)
    score = role_switch_score(weights)
    assert score < 0.1  # the same Gaussians move with the object (pixel-grid aliasing only)
    assert (weights[:, is_obj].sum(axis=1) / weights.sum(axis=1) > 0.999).all()
    handover = np.concatenate([weights[:2], weights[2:, ::-1]])  # frames 2, 3 rendered by other Gaussians
    assert role_switch_score(handover) == pytest.approx((score * 3 - role_switch_score(weights[1:3]) + 1.0) / 3,
                                                        abs=1e-6)


# --------------------------------------------------------------------------- the lifetime dip (secret 1)


def test_the_dip_null_percentile_matches_a_simulated_uniform_null():
    """The critical value read from the package's tables is the 95th percentile of D over
    uniform samples of that size (a seeded simulation, 4,000 samples of n = 200)."""
    rng = np.random.default_rng(7)
    sims = np.array([diptest.dipstat(rng.uniform(size=200)) for _ in range(4000)])
    assert dip_critical_value(200) == pytest.approx(np.quantile(sims, 0.95), rel=0.05)
    assert dip_critical_value(5000) < dip_critical_value(200)  # the null narrows with n


@pytest.mark.parametrize("seed", [0, 1])
def test_a_bimodal_lifetime_mix_has_a_large_excess_and_a_unimodal_one_none(seed):
    rng = np.random.default_rng(seed)
    n = 3000
    everyone = np.ones(n, dtype=bool)
    # two groups: a third short-lived around 0.15, the rest spanning the clip (Δt/T >= 1, capped)
    bimodal = np.r_[rng.normal(0.15, 0.04, n // 3).clip(0.01), rng.uniform(1.0, 5.0, n - n // 3)]
    res = lifetime_dip(bimodal, everyone)
    dip, p = diptest.diptest(np.minimum(bimodal, 1.0))  # the oracle: the package on the capped values
    assert res["dip"] == pytest.approx(dip) and res["p"] == pytest.approx(p) and res["n"] == n
    assert res["excess"] > 0.1 and res["p"] < 1e-3
    assert res["excess"] == pytest.approx(res["dip"] - res["critical"])
    unimodal = rng.beta(2.0, 5.0, n)  # one mode, inside (0, 1)
    flat = lifetime_dip(unimodal, everyone)
    assert flat["excess"] < 0.005 and flat["p"] > 0.01
    assert (flat["excess"] > 0) == (flat["p"] < 0.05)  # the excess is positive exactly when p < 0.05


def test_faded_gaussians_do_not_make_the_histogram_bimodal():
    """A model with a unimodal spread of live lifetimes and as many Gaussians that the clip
    never draws (opacity below θ, alive only long after the clip, or only between two frames):
    the dip counts the live ones only, as the package does on them alone; with the faded ones
    it would be bimodal."""
    model, _ = wall_and_object(moving=False)
    n = len(model)
    rng = np.random.default_rng(3)
    live = np.arange(n) % 2 == 0
    faded_opacity = np.arange(n) % 4 == 1  # sigmoid(o) < θ: Δt = 0
    faded_late = np.arange(n) % 4 == 3  # Δt > 0, but centred 100 s after the 0.4 s clip
    with torch.no_grad():
        s = torch.as_tensor(rng.normal(0.06, 0.005, n), dtype=torch.float32)  # Δt/T about 0.73 ± 0.06: one mode
        model.params["durations"][:] = torch.log(s)
        model.params["opacities"][torch.from_numpy(faded_opacity)] = -6.0
        model.params["times"][torch.from_numpy(faded_late)] = 100.0
    theta, times = 0.05, np.arange(4) / FPS  # a 0.4-s clip of 4 frames
    between = np.arange(n) % 8 == 0  # live, but for 0.01 s only, halfway between frames 1 and 2
    with torch.no_grad():
        model.params["times"][torch.from_numpy(between)] = 0.15
        model.params["durations"][torch.from_numpy(between)] = float(np.log(0.002))
    live &= ~between
    frac = lifetime_fractions(model, theta, duration=0.4)
    drawn = drawn_in_clip(model, theta, times)
    np.testing.assert_array_equal(drawn, live)
    assert (frac[between] > 0).all() and (frac[between] < 0.1).all()
    by_hand = (torch.sigmoid(model.params["opacities"]).detach().numpy()[:, None] * np.exp(
        -0.5 * ((times[None] - model.params["times"].detach().numpy()[:, None])
                / np.exp(model.params["durations"].detach().numpy())[:, None]) ** 2) > theta).any(axis=1)
    np.testing.assert_array_equal(drawn, by_hand)  # o·φ(t) > θ at some frame, by hand
    assert (frac[faded_opacity] == 0).all() and (frac[faded_late] > 0).all()
    res = lifetime_dip(frac, drawn)
    assert res["n"] == int(live.sum())
    assert res["dip"] == pytest.approx(diptest.dipstat(np.minimum(frac[live], 1.0)))
    assert res["excess"] < 0
    everything = lifetime_dip(np.where(faded_late | between, 0.0, frac), np.ones(n, dtype=bool))  # the histogram's view
    assert everything["excess"] > 0.1  # the spike at 0 alone would fake a second group


def test_run_diagnostics_logs_the_dip():
    model, is_obj = wall_and_object()
    with torch.no_grad():  # object short-lived, wall long-lived: two groups
        model.params["durations"][torch.from_numpy(is_obj)] = duration_to_param(0.04, None)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        scene = tiny_scene(Path(tmp), model, is_obj)
        cfg = TrainConfig()
        cfg.model.sh_degree = 0
        m = run_diagnostics(model, scene, cfg, Path(tmp) / "diag", figures=False).metrics()
    frac = lifetime_fractions(model, 0.05, scene.duration)
    assert m["lifetime_dip"] == pytest.approx(diptest.dipstat(np.minimum(frac, 1.0)))
    assert m["lifetime_dip_excess"] > 0.02 and m["lifetime_dip_p"] < 0.01  # an object of ~11 % of the Gaussians


# --------------------------------------------------------------------------- flicker against a noise-free reference


def test_a_still_background_flickers_only_by_the_recorded_noise(tmp_path):
    """A static model rendering its own (noise-free) frames: against the noise-free reference its
    flicker and the excess are 0; the recorded frames carry σ = 0.02 of noise, which the old
    reference (``flicker_static_gt_noisy``) measures — numpy's std of those frames is the oracle."""
    model, is_obj = wall_and_object(moving=False)
    scene = tiny_scene(tmp_path, model, is_obj, n_frames=8)
    clean = np.asarray(scene.decode(0)).copy()
    rng = np.random.default_rng(0)
    noisy = np.clip(np.round(clean + rng.normal(0.0, 0.02 * 255, clean.shape)), 0, 255).astype(np.uint8)
    scene.decode = lambda i: noisy
    (tmp_path / "gt" / "clean").mkdir()
    np.save(tmp_path / "gt" / "clean" / "cam00.npy", clean)
    cfg = TrainConfig()
    cfg.model.sh_degree = 0
    m = run_diagnostics(model, scene, cfg, tmp_path / "diag", figures=False).metrics()
    static = (np.load(tmp_path / "gt" / "objects" / "cam00.npy") == 0).all(axis=0)
    assert m["flicker_static_gt"] == 0.0  # the same noise-free frame 8 times
    assert m["flicker_static"] < 1e-4 and abs(m["flicker_static_excess"]) < 1e-4
    expected = (noisy.astype(np.float64) / 255).std(axis=0).mean(axis=-1)[static].mean()
    assert m["flicker_static_gt_noisy"] == pytest.approx(expected) and m["flicker_static_gt_noisy"] > 0.015
    with np.load(tmp_path / "diag" / "xt_slice.npz") as xt:  # the saved slice keeps both ground truths
        np.testing.assert_array_equal(xt["gt_clean"], clean[:, int(xt["row"])])
        np.testing.assert_array_equal(xt["gt"], noisy[:, int(xt["row"])])
