"""Initial velocities of the triangulated points, one keyframe to the next.

``knn_velocity`` is the FreeTimeGS rule: a point of keyframe k moves towards the mean of its
k nearest neighbours in keyframe k+1's point set, ``v = mean((x_next - x) / dt)``.
``keyframe_velocities`` applies it to every keyframe; the last keyframe has no successor and
uses the previous keyframe backwards (``dt < 0``), which gives ``(x - x_prev) / |dt|``. A
scene with a single keyframe gets zero velocity.

``cfg.velocity == "flow"`` selects the flow-guided velocity of FreeTimeGS++
(``ftgspp.init.flow_velocity``), which starts from these kNN velocities and replaces them
where the optical flow is valid; any other value is an ``InputError``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ftgspp.config import InitConfig
from ftgspp.errors import InputError


def knn_velocity(points_t: np.ndarray, points_next: np.ndarray, dt: float, k: int = 3) -> np.ndarray:
    """Mean over the ``k`` nearest neighbours in ``points_next`` of ``(x_next - x) / dt``.

    points_t [M, 3], points_next [M2, 3] -> velocities [M, 3] (float32, world units / s).
    ``dt`` is the signed time from ``points_t`` to ``points_next`` and must be non-zero.
    With an empty ``points_next`` the velocity is zero; with fewer than ``k`` points all of
    them are used.
    """
    points_t = np.asarray(points_t, dtype=np.float64).reshape(-1, 3)  # [M, 3]
    points_next = np.asarray(points_next, dtype=np.float64).reshape(-1, 3)  # [M2, 3]
    if dt == 0:
        raise ValueError("knn_velocity: dt must be non-zero")
    if len(points_t) == 0 or len(points_next) == 0:
        return np.zeros((len(points_t), 3), dtype=np.float32)
    k = max(1, min(int(k), len(points_next)))
    _, idx = cKDTree(points_next).query(points_t, k=k)
    idx = idx.reshape(len(points_t), k)  # [M, k]
    target = points_next[idx].mean(axis=1)  # [M, 3]
    return ((target - points_t) / dt).astype(np.float32)


def check_velocity_mode(cfg: InitConfig) -> None:
    """Raise ``InputError`` unless ``cfg.velocity``, ``cfg.matcher`` and ``cfg.flow_combine`` name
    available methods (before the expensive matching)."""
    if cfg.velocity not in ("knn", "flow"):
        raise InputError("init.velocity", f"unknown value {cfg.velocity!r}; expected 'knn' or 'flow'")
    if getattr(cfg, "matcher", "sift") not in ("sift", "dense", "known"):
        raise InputError("init.matcher", f"unknown value {cfg.matcher!r}; expected 'sift', 'dense' or 'known'")
    combine = getattr(cfg, "flow_combine", "mean")
    if combine not in ("mean", "lsq", "rays"):
        raise InputError("init.flow_combine", f"unknown value {combine!r}; expected 'mean', 'lsq' or 'rays'")


def keyframe_velocities(
    points: list[np.ndarray], times: list[float], cfg: InitConfig
) -> list[np.ndarray]:
    """Velocity of every point of every keyframe.

    points: per keyframe ``[M_i, 3]``; times: keyframe times in seconds (increasing).
    Returns per keyframe ``[M_i, 3]`` float32.
    """
    check_velocity_mode(cfg)
    n = len(points)
    out = []
    for i in range(n):
        if n == 1:
            out.append(np.zeros((len(points[i]), 3), dtype=np.float32))
            continue
        # last keyframe: look backwards at the previous one (signed dt < 0)
        j = i + 1 if i + 1 < n else i - 1
        out.append(knn_velocity(points[i], points[j], times[j] - times[i], k=cfg.knn_k))
    return out
