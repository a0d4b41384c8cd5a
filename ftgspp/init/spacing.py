"""How far apart the initial points are: the distances their initial scales come from.

Two rules, both over the ``SPACING_K`` = 3 nearest other points (exact kNN, ``scipy.spatial.cKDTree``):

- ``knn_spacing``: the mean distance, among the points of one keyframe (FreeTimeGS here, and the
  budget fill's jitter: ftgspp/init/points.py).
- ``union_spacing``: the root mean square distance, among every keyframe's points together, the
  square floored at ``UNION_FLOOR_SQ``: Spacetime Gaussians' public code concatenates the point
  clouds of every frame of the clip and starts each Gaussian at ``sqrt(max(mean d², 1e-7))``
  (``distCUDA2``, the 3DGS rule). A static surface seen at several keyframes gives points close to
  one another, so this spacing is much smaller than the per-keyframe one there.
  ``model.init_spacing=union`` starts a run from it (``ftgspp/train_state.build_model``), as
  conf/model/stg.yaml sets for STGS.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

SPACING_K = 3  # neighbours for the kNN spacing
UNION_FLOOR_SQ = 1e-7  # the public STGS code's floor on the mean squared distance (torch.clamp_min(dist2, 1e-7))


def _neighbour_distances(points: np.ndarray, k: int) -> np.ndarray:
    """Distances to the ``k`` nearest other points, [M, k] (k already < M)."""
    d, _ = cKDTree(points).query(points, k=k + 1)
    return d[:, 1:]


def knn_spacing(points: np.ndarray, k: int = SPACING_K) -> np.ndarray:
    """Mean distance to the ``k`` nearest other points. [M, 3] -> [M] (NaN if M < 2)."""
    m = len(points)
    if m < 2:
        return np.full(m, np.nan)
    return _neighbour_distances(points, min(k, m - 1)).mean(axis=1)


def union_spacing(point_sets: list[np.ndarray], k: int = SPACING_K) -> list[np.ndarray]:
    """``sqrt(max(mean squared distance to the k nearest other points, UNION_FLOOR_SQ))`` with the
    neighbours sought among all the sets together; returned per set, in its order ([M_i] each; NaN
    everywhere when there are fewer than 2 points in all)."""
    sizes = [len(p) for p in point_sets]
    total = sum(sizes)
    if total < 2:
        return [np.full(m, np.nan) for m in sizes]
    union = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in point_sets])
    d = _neighbour_distances(union, min(k, total - 1))
    rms = np.sqrt(np.maximum((d * d).mean(axis=1), UNION_FLOOR_SQ))
    return np.split(rms, np.cumsum(sizes)[:-1])
