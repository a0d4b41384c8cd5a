"""Ground-truth scores of the secrets on tiny constructed renders with known answers:
per-Gaussian mask weights (against the rendered alpha), the lifetime partition contrast
(secret 1), role switching (secret 2) and static-background flicker (secret 4)."""

from __future__ import annotations

import numpy as np
import pytest
from test_diagnostics import camera, object_masks, wall_and_object

from ftgspp.diagnostics.lifetimes import mask_weights, partition_scores, role_switch_score
from ftgspp.diagnostics.motion import composite, static_flicker


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
