"""kNN velocities against brute-force nearest neighbours and known rigid motions."""

from __future__ import annotations

import numpy as np
import pytest

from ftgspp.config import InitConfig
from ftgspp.errors import InputError
from ftgspp.init import knn_velocity
from ftgspp.init.velocity import keyframe_velocities


def brute_force_knn_velocity(x: np.ndarray, y: np.ndarray, dt: float, k: int) -> np.ndarray:
    d = np.linalg.norm(x[:, None] - y[None], axis=2)  # [M, M2]
    idx = np.argsort(d, axis=1)[:, :k]
    return (y[idx] - x[:, None]).mean(axis=1) / dt


def test_matches_brute_force_neighbours():
    rng = np.random.default_rng(0)
    x, y = rng.normal(size=(200, 3)), rng.normal(size=(150, 3))
    for k in (1, 3, 5):
        v = knn_velocity(x, y, 0.25, k=k)
        assert v.shape == (200, 3) and v.dtype == np.float32
        np.testing.assert_allclose(v, brute_force_knn_velocity(x, y, 0.25, k), rtol=1e-5, atol=1e-5)


def test_recovers_rigid_translation_k1():
    rng = np.random.default_rng(1)
    x = rng.uniform(-5, 5, size=(300, 3))
    velocity = np.array([0.3, -0.1, 0.2])  # small against the point spacing
    v = knn_velocity(x, x + velocity * 0.1, dt=0.1, k=1)
    np.testing.assert_allclose(v, np.broadcast_to(velocity, v.shape), atol=1e-5)


def test_recovers_rigid_translation_k3_clusters():
    # each point becomes a tight triangle of three points centred on its translated position:
    # the mean of its 3 nearest neighbours is exactly the translated point
    rng = np.random.default_rng(2)
    grid = np.stack(np.meshgrid(*[np.arange(5.0)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    x = 3.0 * grid + rng.uniform(-0.3, 0.3, size=grid.shape)  # well separated against the motion
    velocity = np.array([-1.0, 0.5, 2.0])
    dt = 1 / 3
    ang = 2 * np.pi * np.arange(3) / 3
    tri = 1e-3 * np.stack([np.cos(ang), np.sin(ang), np.zeros(3)], axis=1)  # sums to zero
    y = (x + velocity * dt)[:, None] + tri[None]
    v = knn_velocity(x, y.reshape(-1, 3), dt, k=3)
    np.testing.assert_allclose(v, np.broadcast_to(velocity, v.shape), atol=1e-4)


def test_edge_cases():
    x = np.zeros((4, 3))
    assert np.array_equal(knn_velocity(x, np.zeros((0, 3)), 0.1), np.zeros((4, 3)))
    assert knn_velocity(np.zeros((0, 3)), x, 0.1).shape == (0, 3)
    # fewer candidates than k: all of them are used
    two = np.array([[1.0, 0, 0], [3.0, 0, 0]])
    np.testing.assert_allclose(knn_velocity(np.zeros((1, 3)), two, 1.0, k=3), [[2, 0, 0]])
    with pytest.raises(ValueError):
        knn_velocity(x, x, 0.0)


def test_keyframes_forward_and_last_backward():
    rng = np.random.default_rng(3)
    base = rng.uniform(-5, 5, size=(200, 3))
    velocity = np.array([0.2, 0.0, -0.1])
    times = [0.0, 0.5, 1.0]
    points = [base + velocity * t for t in times]
    vs = keyframe_velocities(points, times, InitConfig(knn_k=1))
    assert len(vs) == 3
    for v in vs:  # the last keyframe looks back at the previous one and gets the same velocity
        np.testing.assert_allclose(v, np.broadcast_to(velocity, v.shape), atol=1e-5)
    single = keyframe_velocities(points[:1], times[:1], InitConfig())
    assert np.array_equal(single[0], np.zeros((200, 3)))


def test_unknown_mode_is_an_input_error():
    with pytest.raises(InputError, match="init.velocity"):
        keyframe_velocities([np.zeros((1, 3))], [0.0], InitConfig(velocity="magic"))
