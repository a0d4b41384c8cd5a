"""Two-view geometry shared by the initialisers: epipolar constraint, projection, camera pairs.

Used by the sparse (SIFT, ftgspp/init/points.py) and the dense (ftgspp/init/dense.py) matchers
and by the ground-truth scoring of an initialisation (ftgspp/init/quality.py).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ftgspp.data.scene import Camera, Scene


def fundamental_matrix(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """F [3, 3] with ``x_b^T F x_a = 0`` for pixels of the same world point in a and b."""
    R = cam_b.R @ cam_a.R.T  # a-camera to b-camera rotation
    t = cam_b.T - R @ cam_a.T
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    E = tx @ R
    return np.linalg.inv(cam_b.K).T @ E @ np.linalg.inv(cam_a.K)


def sampson_distance(F: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> np.ndarray:
    """First-order geometric epipolar error in pixels. pa, pb [M, 2] -> [M]."""
    xa = np.hstack([pa, np.ones((len(pa), 1))])  # [M, 3]
    xb = np.hstack([pb, np.ones((len(pb), 1))])
    Fxa = xa @ F.T  # [M, 3] epipolar lines in b
    Ftxb = xb @ F  # [M, 3] epipolar lines in a
    num = np.sum(xb * Fxa, axis=1) ** 2
    den = Fxa[:, 0] ** 2 + Fxa[:, 1] ** 2 + Ftxb[:, 0] ** 2 + Ftxb[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-300))


def project(cam: Camera, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted pixels [M, 2] and camera-space depths [M] of world points X [M, 3]."""
    Xc = X @ cam.R.T + cam.T  # [M, 3]
    z = Xc[:, 2]
    uv = Xc @ cam.K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return uv[:, :2] / uv[:, 2:3], z


def neighbor_pairs(scene: Scene, k: int) -> list[tuple[int, int]]:
    """Unordered pairs (camera indices into ``scene.cameras``, i < j): each training camera
    with its ``k`` nearest training cameras by centre distance, each pair once."""
    ids = list(scene.train_ids)
    if len(ids) < 2:
        return []
    centers = np.stack([scene.cameras[i].center for i in ids])
    k = max(1, min(int(k), len(ids) - 1))
    _, nn = cKDTree(centers).query(centers, k=k + 1)  # [C, k+1], column 0 is (usually) itself
    pairs = set()
    for a, row in enumerate(nn):
        for b in row:
            if b != a:
                pairs.add((min(ids[a], ids[b]), max(ids[a], ids[b])))
    return sorted(pairs)


def pixel_colors(image: np.ndarray, pix: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] at the nearest pixel. pix [M, 2] -> [M, 3] float64."""
    h, w = image.shape[:2]
    x = np.clip(np.rint(pix[:, 0]).astype(np.int64), 0, w - 1)
    y = np.clip(np.rint(pix[:, 1]).astype(np.int64), 0, h - 1)
    return image[y, x].astype(np.float64) / 255.0


def triangulate_pair(cam_a: Camera, cam_b: Camera, pa: np.ndarray, pb: np.ndarray, near: float, far: float,
                     max_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Points ``X [M, 3]`` triangulated from undistorted pixel pairs ``pa``, ``pb`` ``[M, 2]``
    (``cv2.triangulatePoints``) and the mask ``[M]`` of those in front of both cameras, with
    camera depth in ``[near, far]``, reprojecting within ``max_px`` in both views."""
    Xh = cv2.triangulatePoints(cam_a.projection, cam_b.projection, pa.T.copy(), pb.T.copy())  # [4, M]
    w = Xh[3]
    finite = np.abs(w) > 1e-12
    X = (Xh[:3] / np.where(finite, w, 1.0)).T  # [M, 3]
    keep = finite
    for cam, p in ((cam_a, pa), (cam_b, pb)):
        uv, z = project(cam, X)
        keep &= (z > 0) & (z >= near) & (z <= far) & (np.linalg.norm(uv - p, axis=1) < max_px)
    return X, keep
