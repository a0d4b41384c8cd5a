"""Dense-matching initialisation (``init.matcher=dense``) on the exact two-plane scene of
``test_points.py``: the points lie on the true planes with their true colours, there are many
more of them than SIFT gives, the cap is the paper's density and the set does not depend on the
optimisation seed; initial velocities are scored against a generated scene's ground truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ftgspp.data.synthetic.build import generate
from ftgspp.init import initialize, triangulate_keyframe
from ftgspp.init.dense import PAPER_CANDIDATES_PER_PIXEL, candidates_per_frame, triangulate_keyframe_dense
from tests.init.test_points import N_FRAMES, STRIDE, TEST_CAM, H, W, explicit, plane_distance, scene, true_color

__all__ = ["scene"]  # the module fixture, shared


def test_dense_points_lie_on_the_planes_with_their_colours_and_outnumber_sift(scene):
    cfg = explicit(matcher="dense", candidates_per_frame=10**9)  # no cap: every accepted match
    for frame in (0, 4):
        t = scene.times[frame]
        P, C, counts = triangulate_keyframe_dense(scene, frame, cfg, 1.0, 20.0)
        sift, _ = triangulate_keyframe(scene, frame, explicit(), 1.0, 20.0)
        assert len(P) > 10 * len(sift) and counts["points"] == len(P) <= counts["epipolar"] <= counts["consistent"]
        d = plane_distance(P.astype(np.float64), t)
        # most points on a plane; a tail (occlusion edges, the square's rim) is not
        assert np.median(d) < 0.03 and np.quantile(d, 0.8) < 0.15, (np.median(d), np.quantile(d, 0.8))
        assert np.median(np.abs(C - true_color(P.astype(np.float64), t)).max(axis=1)) < 0.1
    assert TEST_CAM not in scene.decoded


def test_the_cap_is_the_papers_density_even_and_independent_of_the_seed(scene):
    cap = candidates_per_frame(scene, explicit(matcher="dense"))
    assert cap == round(PAPER_CANDIDATES_PER_PIXEL * W * H) and 0.5 < PAPER_CANDIDATES_PER_PIXEL < 0.52
    P, _, _ = triangulate_keyframe_dense(scene, 0, explicit(matcher="dense", candidates_per_frame=500), 1.0, 20.0)
    assert len(P) == 500
    a = initialize(scene, explicit(matcher="dense", fixed_seed=None), budget=800, seed=1)
    b = initialize(scene, explicit(matcher="dense"), budget=800, seed=2)
    kf = len(range(0, N_FRAMES, STRIDE))
    assert a.stats["init_points_total"] == b.stats["init_points_total"] == kf * cap
    assert a.stats["init_real_share"] == 1.0 and a.stats["init_matcher_dense"] == 1.0
    sift = initialize(scene, explicit(), budget=20_000, seed=1)
    assert sift.stats["init_real_share"] < 1.0 and sift.stats["init_matcher_dense"] == 0.0


def test_velocity_error_is_scored_against_the_scenes_ground_truth(tmp_path):
    """On a generated scene with ground truth: true velocities score 0, zero velocities score the
    true speed on moving points and 0 on static ones."""
    from ftgspp.config import DataConfig
    from ftgspp.data.load import load_scene
    from ftgspp.init.points import depth_range
    from ftgspp.init.quality import ground_truth_velocities, velocity_error

    root = generate(tmp_path / "s", preset="studio", seed=0, width=96, height=72, n_frames=4, n_cameras=5)
    s = load_scene(DataConfig(path=str(root)))
    cfg = replace(explicit(matcher="dense"), depth_prior="auto", near=None, far=None)
    pts, _, _ = triangulate_keyframe_dense(s, 0, cfg, *depth_range(s, cfg))
    truth = ground_truth_velocities(s, [0], [pts])
    vel, found = truth[0]
    assert found.mean() > 0.5  # most dense points sit on a surface some camera sees
    perfect = velocity_error(s, [0], [pts], [np.where(found[:, None], vel, 0.0)])
    assert perfect["init_velocity_error_moving"] == 0 and perfect["init_velocity_error_static"] == 0
    still = velocity_error(s, [0], [pts], [np.zeros_like(pts)])
    assert still["init_velocity_error_moving"] == still["init_velocity_true_speed_moving"] > 0.1
    assert still["init_velocity_error_static"] == 0
