"""Dense-matching keyframe points (``init.matcher=dense``): the paper's initialisation, scaled down.

The paper initialises from dense correspondences between each camera and its two nearest
cameras (RoMa), about 700k candidate points per frame for a DyNeRF view of 1352 × 1014 px
(about one per two pixels of a view), sampled to the budget. Here, per keyframe and per pair
of neighbouring training cameras (``neighbor_pairs``, each unordered pair once):

1. dense flow from camera a's image to camera b's and back (the flow model of
   ``init.flow_model``; OpenCV DIS with its ``fine`` preset by default: a flow between two views
   is a dense matcher, and at full resolution its points' median depth error on the studio
   scene is 0.7 %, against 0.3 % for SIFT's far fewer points);
2. forward–backward consistency: a pixel is kept where the round trip comes back, the soft
   weight of ``ftgspp.init.flow.forward_backward_weight`` above 1/e (Sundaram et al.'s test),
   and where camera a's image has texture to match (``TEXTURE_MIN``);
3. the epipolar check of the SIFT path: Sampson distance < ``init.max_reproj_px`` for the
   undistorted pixel pair;
4. ``cv2.triangulatePoints``, kept in front of both cameras, inside ``[near, far]`` and
   reprojecting within ``init.max_reproj_px`` in both views; colour = mean of the two pixels.

A pixel of a pair's two cameras yields at most one point per keyframe, as a SIFT feature does: a
pair skips pixels an earlier pair already used in either of its cameras. Pairs with no camera in
common can still triangulate one surface twice (on the two-plane test scene a third camera's
pixel holds a median of 4 points before the cap); the even cap below thins them, and the kNN
spacing is floored so initial scales stay positive. The candidates are then cut to
``init.candidates_per_frame`` (``None``: half the pixel count of one training view, the paper's
density) by an even, deterministic subsample, so a point set does not depend on the optimisation
seed. The budget fit in ``points.initialize``
samples from there.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from ftgspp.config import InitConfig
from ftgspp.data.scene import Camera, Scene
from ftgspp.init.flow import forward_backward_weight, get_flow_model
from ftgspp.init.two_view import fundamental_matrix, neighbor_pairs, pixel_colors, sampson_distance, triangulate_pair

log = logging.getLogger("ftgspp.init")

PAPER_CANDIDATES_PER_PIXEL = 700_000 / (1352 * 1014)  # ≈ 0.51: candidates per pixel of one view
FB_KEEP = float(np.exp(-1.0))  # the soft forward-backward weight's hard threshold
# Texture a match needs in camera a: the smaller eigenvalue of the 5x5 structure tensor of the
# grey image in [0, 1] (cv2.cornerMinEigenVal). Flow in flat regions is interpolated, consistent
# both ways and wrong in depth; on the two-plane test scene this drops 17 % of the matches and
# the points more than 0.15 units off a plane from 12 % to 9 %.
TEXTURE_MIN = 1e-3


def candidates_per_frame(scene: Scene, cfg: InitConfig) -> int:
    """``cfg.candidates_per_frame``, or the paper's density for this scene's training views."""
    if cfg.candidates_per_frame is not None:
        return int(cfg.candidates_per_frame)
    cam = scene.cameras[scene.train_ids[0]]
    return max(1, round(PAPER_CANDIDATES_PER_PIXEL * cam.width * cam.height))


def _undistort(cam: Camera, pix: np.ndarray) -> np.ndarray:
    if cam.dist is None or not len(pix) or not np.any(np.asarray(cam.dist) != 0):
        return pix
    return cv2.undistortPoints(pix.reshape(-1, 1, 2), cam.K, np.asarray(cam.dist), P=cam.K).reshape(-1, 2)


def _pixel(xy: np.ndarray, w: int) -> np.ndarray:
    """Flat index of the pixel containing each point ``xy [M, 2]`` (callers keep them inside)."""
    return np.rint(xy[:, 1]).astype(np.int64) * w + np.rint(xy[:, 0]).astype(np.int64)


def pair_matches(img_a: np.ndarray, img_b: np.ndarray, flow_model) -> tuple[np.ndarray, np.ndarray]:
    """Forward–backward consistent dense matches ``(pix_a [M, 2], pix_b [M, 2])`` from a to b
    (pixel centres of a, in distorted image coordinates)."""
    fw = flow_model(img_a, img_b)  # [H, W, 2]
    ok = forward_backward_weight(fw, flow_model(img_b, img_a)).ravel() > FB_KEEP  # also: lands inside b
    grey = cv2.cvtColor(img_a, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    ok &= cv2.cornerMinEigenVal(grey, 5).ravel() > TEXTURE_MIN
    h, w = fw.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w]
    pa = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)  # [HW, 2]
    return pa[ok], (pa + fw.reshape(-1, 2))[ok]


def triangulate_keyframe_dense(
    scene: Scene, frame: int, cfg: InitConfig, near: float, far: float
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Points ``[M, 3]``, colours ``[M, 3]`` (float32) and counts of loaded frame ``frame``."""
    name = getattr(cfg, "flow_model", "dis")
    flow_model = get_flow_model(name, preset="fine") if name == "dis" else get_flow_model(name)
    pairs = neighbor_pairs(scene, cfg.neighbor_cams)
    cams = sorted({c for p in pairs for c in p})
    images = {c: np.ascontiguousarray(scene.frames(c)[frame]) for c in cams}
    used = {c: np.zeros(images[c].shape[0] * images[c].shape[1], dtype=bool) for c in cams}
    points, colors = [], []
    counts = dict(pairs=len(pairs), consistent=0, epipolar=0, points=0)
    for a, b in pairs:
        cam_a, cam_b = scene.cameras[a], scene.cameras[b]
        pa, pb = pair_matches(images[a], images[b], flow_model)
        wa, wb = images[a].shape[1], images[b].shape[1]
        ia, ib = _pixel(pa, wa), _pixel(pb, wb)
        free = ~used[a][ia] & ~used[b][ib]
        pa, pb, ia, ib = pa[free], pb[free], ia[free], ib[free]
        counts["consistent"] += len(pa)
        ua, ub = _undistort(cam_a, pa), _undistort(cam_b, pb)
        ok = sampson_distance(fundamental_matrix(cam_a, cam_b), ua, ub) < cfg.max_reproj_px
        pa, pb, ua, ub, ia, ib = pa[ok], pb[ok], ua[ok], ub[ok], ia[ok], ib[ok]
        counts["epipolar"] += len(pa)
        if not len(pa):
            continue
        X, keep = triangulate_pair(cam_a, cam_b, ua, ub, near, far, cfg.max_reproj_px)
        # one point per pixel of b too: several a-pixels can land in one b-pixel
        keep &= _first(ib, keep)
        used[a][ia[keep]] = True
        used[b][ib[keep]] = True
        points.append(X[keep])
        colors.append(0.5 * (pixel_colors(images[a], pa[keep]) + pixel_colors(images[b], pb[keep])))
    P = np.concatenate(points) if points else np.zeros((0, 3))
    C = np.concatenate(colors) if colors else np.zeros((0, 3))
    cap = candidates_per_frame(scene, cfg)
    if len(P) > cap:  # an even subsample: every k-th candidate, deterministic
        idx = np.unique(np.linspace(0, len(P) - 1, cap).round().astype(np.int64))
        P, C = P[idx], C[idx]
    counts["points"] = len(P)
    log.info(
        "init: frame %d: %d views, %d pairs, %d consistent dense matches, %d epipolar inliers, %d points (dense)",
        frame, len(cams), len(pairs), counts["consistent"], counts["epipolar"], len(P),
    )
    return P.astype(np.float32), C.astype(np.float32), counts


def _first(ids: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``[M]`` True at the first masked occurrence of each id (False where ``mask`` is False)."""
    out = np.zeros(len(ids), dtype=bool)
    sel = np.flatnonzero(mask)
    _, first = np.unique(ids[sel], return_index=True)
    out[sel[first]] = True
    return out
