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

**When the points are not trusted** (``init.dense_check``, docs/init.md). Two ways were measured to
lose PSNR against SIFT + fill on the development scenes of docs/init.md, and ``auto`` (the default)
checks both, once per run, then uses the SIFT matcher (and the budget fill) for the whole run if
either fails; ``off`` always keeps the dense points.

1. *Coverage.* Dense matches exist only where a view has texture (``TEXTURE_MIN``); where the
   textured parts cover little of the views (a few objects before a smooth backdrop) the budget fill
   copies the dense points in place (its jitter is half their kNN spacing, tiny for dense points) and
   the rest of every view starts with no point, while SIFT's few points, copied with a jitter of
   their wide spacing, spread over it. ``view_coverage``: the share of the cells of a
   ``COVERAGE_GRID`` over each training view that hold a projected dense point of a keyframe (mean
   over the views), measured on the keyframe's candidates *before* the cut to
   ``init.candidates_per_frame`` (where matches exist at all, not how many a run keeps: one that
   asks for 50 points a keyframe covers few cells by its own choice); its median over the keyframes
   must reach ``COVERAGE_MIN``. Neither the size of the views nor the points' depth error sorted
   these runs.
2. *Agreement with SIFT.* Where the flow is wrong on the textured parts too (wide camera spacing:
   large displacements), it disagrees with SIFT's matches where SIFT has them: the median over the
   keyframes' ``sift_depth_gaps`` (relative depth gaps at SIFT's kept keypoints) must stay within
   ``AGREEMENT_MAX``. Each keyframe's flows are dropped once its gaps are measured.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np

from ftgspp.config import InitConfig
from ftgspp.data.scene import Camera, Scene
from ftgspp.errors import InputError
from ftgspp.init.flow import forward_backward_weight, get_flow_model, sample_bilinear
from ftgspp.init.two_view import (
    fundamental_matrix,
    neighbor_pairs,
    pixel_colors,
    project,
    sampson_distance,
    triangulate_pair,
)

log = logging.getLogger("ftgspp.init")

PAPER_CANDIDATES_PER_PIXEL = 700_000 / (1352 * 1014)  # ≈ 0.51: candidates per pixel of one view
FB_KEEP = float(np.exp(-1.0))  # the soft forward-backward weight's hard threshold
# Texture a match needs in camera a: the smaller eigenvalue of the 5x5 structure tensor of the
# grey image in [0, 1] (cv2.cornerMinEigenVal). Flow in flat regions is interpolated, consistent
# both ways and wrong in depth; on the two-plane test scene this drops 17 % of the matches and
# the points more than 0.15 units off a plane from 12 % to 9 %.
TEXTURE_MIN = 1e-3
# init.dense_check=auto, coverage: the grid of cells (across, down) laid over each training view, and
# the share of them the dense points of a keyframe must reach (mean over the views, median over the
# keyframes). On the development scenes (docs/init.md) dense matching lost or tied in PSNR at coverages
# 0.28-0.46 and gained at 0.53-0.98; the presets of the quick profile reach 0.98.
COVERAGE_GRID = (16, 12)
COVERAGE_MIN = 0.5
# init.dense_check=auto, agreement with SIFT: the largest median relative depth disagreement between
# the dense flow and SIFT's matches at SIFT's kept keypoints. On the development scenes it is 0.008-0.040,
# except on the studio seen by 5 cameras 12.5 degrees apart: 0.25, where dense matching lost 4-5 dB.
AGREEMENT_MAX = 0.1
DENSE_CHECKS = ("auto", "off")


def candidates_per_frame(scene: Scene, cfg: InitConfig) -> int:
    """``cfg.candidates_per_frame``, or the paper's density for this scene's training views."""
    if cfg.candidates_per_frame is not None:
        return int(cfg.candidates_per_frame)
    cam = scene.cameras[scene.train_ids[0]]
    return max(1, round(PAPER_CANDIDATES_PER_PIXEL * cam.width * cam.height))


def check_option(cfg: InitConfig) -> str:
    """``init.dense_check``, checked (``InputError`` naming the key otherwise)."""
    check = getattr(cfg, "dense_check", "off")
    if check not in DENSE_CHECKS:
        raise InputError("init.dense_check", f"unknown value {check!r}; expected {' or '.join(DENSE_CHECKS)}")
    return check


def view_coverage(scene: Scene, points: np.ndarray) -> float:
    """The share of ``COVERAGE_GRID`` cells of each training view holding at least one of ``points
    [M, 3]`` (projected, in front of the camera), averaged over the training views."""
    gx, gy = COVERAGE_GRID
    shares = []
    for i in scene.train_ids:
        cam = scene.cameras[i]
        uv, z = project(cam, np.asarray(points, dtype=np.float64).reshape(-1, 3))
        with np.errstate(invalid="ignore"):
            cx, cy = np.floor((uv[:, 0] + 0.5) * gx / cam.width), np.floor((uv[:, 1] + 0.5) * gy / cam.height)
            ok = (z > 0) & (cx >= 0) & (cx < gx) & (cy >= 0) & (cy < gy)
        cells = np.unique(cy[ok].astype(np.int64) * gx + cx[ok].astype(np.int64))
        shares.append(len(cells) / (gx * gy))
    return float(np.mean(shares)) if shares else 0.0


def sift_depth_gaps(scene: Scene, matches: list, flows: dict) -> np.ndarray:
    """Relative depth gaps ``[m]`` between the dense flow and SIFT in one keyframe: for every kept SIFT
    match of every camera pair (``matches``: ``(a, b, pix_a [m, 2], X [m, 3])`` per pair, each pair's own
    matches, ``points.sift_pair_matches(exclusive=False)``; ``flows``: the dense forward flows by pair),
    the point triangulated from ``pix_a`` and where the flow from a to b takes it, against SIFT's point,
    as ``|z_dense - z_sift| / z_sift`` in camera a (inf where the flow's rays do not meet in front)."""
    gaps = []
    for a, b, pix_a, X in matches:
        fw = flows.get((a, b))
        if fw is None or not len(pix_a):
            continue
        cam_a, cam_b = scene.cameras[a], scene.cameras[b]
        step, _ = sample_bilinear(fw, pix_a)  # [m, 2]
        Xd, _ = triangulate_pair(cam_a, cam_b, _undistort(cam_a, pix_a), _undistort(cam_b, pix_a + step),
                                 0.0, np.inf, np.inf)
        zd, zs = project(cam_a, Xd)[1], project(cam_a, np.asarray(X, dtype=np.float64))[1]
        with np.errstate(invalid="ignore", divide="ignore"):
            e = np.abs(zd - zs) / zs
        gaps.append(np.where(np.isfinite(e) & (zd > 0), e, np.inf))
    return np.concatenate(gaps) if gaps else np.zeros(0)


def dense_trusted(cfg: InitConfig, coverages: list[float], gaps: list[np.ndarray] | None = None
                  ) -> tuple[bool, dict[str, float]]:
    """Whether ``init.dense_check`` keeps the dense points of every keyframe, and what it measured:
    ``coverage``, the median of the keyframes' ``coverages`` (``view_coverage`` of each keyframe's
    candidates before the cap: ``triangulate_keyframe_dense(..., measure_coverage=True)``), and
    ``disagreement``, the median of the keyframes' ``sift_depth_gaps`` (``gaps``; absent without any)."""
    check = check_option(cfg)
    seen = {"coverage": float(np.median(coverages)) if len(coverages) else 0.0}
    pooled = np.concatenate(gaps) if gaps else np.zeros(0)
    if len(pooled):
        seen["disagreement"] = float(np.median(pooled))
    covered = seen["coverage"] >= COVERAGE_MIN
    agrees = seen.get("disagreement", 0.0) <= AGREEMENT_MAX
    return check == "off" or (covered and agrees), seen


def _undistort(cam: Camera, pix: np.ndarray) -> np.ndarray:
    if cam.dist is None or not len(pix) or not np.any(np.asarray(cam.dist) != 0):
        return pix
    return cv2.undistortPoints(pix.reshape(-1, 1, 2), cam.K, np.asarray(cam.dist), P=cam.K).reshape(-1, 2)


def _pixel(xy: np.ndarray, w: int) -> np.ndarray:
    """Flat index of the pixel containing each point ``xy [M, 2]`` (callers keep them inside)."""
    return np.rint(xy[:, 1]).astype(np.int64) * w + np.rint(xy[:, 0]).astype(np.int64)


def pair_matches(img_a: np.ndarray, img_b: np.ndarray, flow_model, fw: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Forward–backward consistent dense matches ``(pix_a [M, 2], pix_b [M, 2])`` from a to b
    (pixel centres of a, in distorted image coordinates); ``fw``: the flow from a to b if known."""
    fw = flow_model(img_a, img_b) if fw is None else fw  # [H, W, 2]
    ok = forward_backward_weight(fw, flow_model(img_b, img_a)).ravel() > FB_KEEP  # also: lands inside b
    grey = cv2.cvtColor(img_a, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    ok &= cv2.cornerMinEigenVal(grey, 5).ravel() > TEXTURE_MIN
    h, w = fw.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w]
    pa = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)  # [HW, 2]
    return pa[ok], (pa + fw.reshape(-1, 2))[ok]


def triangulate_keyframe_dense(
    scene: Scene, frame: int, cfg: InitConfig, near: float, far: float, flows: dict | None = None,
    measure_coverage: bool = False,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Points ``[M, 3]``, colours ``[M, 3]`` (float32) and counts of loaded frame ``frame``; ``flows``,
    if given, receives each camera pair's forward flow ``[H, W, 2]`` under ``(a, b)``;
    ``measure_coverage``: the counts' ``coverage`` is ``view_coverage`` of the candidates before the
    cut to ``init.candidates_per_frame`` (the check's, module docstring)."""
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
        fw = flow_model(images[a], images[b])
        if flows is not None:
            flows[(a, b)] = fw
        pa, pb = pair_matches(images[a], images[b], flow_model, fw)
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
    if measure_coverage:
        counts["coverage"] = view_coverage(scene, P)
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
