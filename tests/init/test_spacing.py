"""The initial points' spacings (ftgspp/init/spacing.py) against brute-force distances."""

from __future__ import annotations

import numpy as np
import pytest

from ftgspp.init.spacing import UNION_FLOOR_SQ, knn_spacing, union_spacing


def brute_distances(points: np.ndarray, k: int) -> np.ndarray:
    """Distances to the k nearest other points, from the full distance matrix (the oracle)."""
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return np.sort(d, axis=1)[:, :k]


def test_knn_spacing_is_the_mean_distance_to_the_three_nearest() -> None:
    pts = np.random.default_rng(0).normal(size=(60, 3))
    np.testing.assert_allclose(knn_spacing(pts), brute_distances(pts, 3).mean(axis=1), rtol=1e-12)
    assert np.isnan(knn_spacing(pts[:1])).all() and knn_spacing(pts[:2])[0] == pytest.approx(
        np.linalg.norm(pts[0] - pts[1]))


def test_union_spacing_searches_every_set_together_with_the_rms_rule_and_its_floor() -> None:
    rng = np.random.default_rng(1)
    surface = rng.uniform(-1, 1, size=(40, 3))
    sets = [surface + rng.normal(scale=1e-3, size=surface.shape),  # a surface seen at four keyframes
            surface.copy(), surface.copy(), surface.copy(),  # ... three times exactly (identical matches)
            rng.uniform(-1, 1, size=(7, 3))]
    got = union_spacing(sets)
    assert [len(g) for g in got] == [40, 40, 40, 40, 7]  # per set, in its order
    union = np.concatenate(sets)
    d = brute_distances(union, 3)
    want = np.sqrt(np.maximum((d * d).mean(axis=1), UNION_FLOOR_SQ))
    np.testing.assert_allclose(np.concatenate(got), want, rtol=1e-12)
    # its three nearest are the surface point's other sightings (0, 0, ~1e-3): far below a keyframe's own
    # spacing; with only three sightings the third neighbour is another point, and the RMS about 1/sqrt(3) of it
    assert np.all(got[1] < 0.05 * knn_spacing(surface))
    three = union_spacing(sets[1:4])[0]
    nearest_other = brute_distances(surface, 1)[:, 0]
    np.testing.assert_allclose(three, nearest_other / np.sqrt(3), rtol=1e-12)
    # all three neighbours coincide: the floor sqrt(1e-7) (the public code's clamp on the mean square)
    (floored,) = union_spacing([np.zeros((4, 3))])
    np.testing.assert_allclose(floored, np.sqrt(UNION_FLOOR_SQ))


def test_union_spacing_of_fewer_than_two_points_is_nan() -> None:
    assert [len(g) for g in union_spacing([np.zeros((0, 3)), np.ones((1, 3))])] == [0, 1]
    assert np.isnan(union_spacing([np.zeros((0, 3)), np.ones((1, 3))])[1]).all()
    a, b = union_spacing([np.zeros((1, 3)), np.array([[3.0, 4.0, 0.0]])])
    assert a[0] == pytest.approx(5.0) and b[0] == pytest.approx(5.0)
