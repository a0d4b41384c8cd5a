"""Initial 4D Gaussians from multi-view video: triangulated keyframe points.

For every keyframe (every ``cfg.keyframe_stride``-th loaded frame) and every training camera
(the held-out test cameras are never read), with ``init.matcher=sift`` (``dense``: the paper's
dense matching, ftgspp/init/dense.py, unless ``init.dense_check`` does not trust its points on this
scene: then these SIFT steps, and the run's ``init_dense_fallback`` is 1):

1. SIFT features (``cv2.SIFT_create(nfeatures=cfg.max_features)``).
2. Each view is matched to its ``cfg.neighbor_cams`` nearest training cameras by centre
   distance (each unordered pair once), brute-force L2 with Lowe's ratio test.
3. Matches are filtered with the known geometry: Sampson distance to the epipolar line of
   the fundamental matrix built from the two calibrated cameras, < ``cfg.max_reproj_px``.
4. ``cv2.triangulatePoints`` with ``Camera.projection``; a point is kept if it is in front
   of both cameras with depth in ``[near, far]`` (``depth_range``) and reprojects within
   ``cfg.max_reproj_px`` in both views. Colour = mean of the two pixel colours.

A feature yields at most one point per keyframe: later pairs skip a used one (near-duplicates
would collapse the kNN spacing, and so the initial scales, to zero).

``initialize`` then adds kNN velocities (``ftgspp.init.velocity``), temporal centres (keyframe time
+ uniform jitter in +-stride/fps/2, not clipped to the loaded time span), kNN spacing (3 nearest
neighbours in the same keyframe, floored at 1e-4 x the median so scales stay positive; and the union
spacing of Spacetime Gaussians' rule, ftgspp/init/spacing.py) and fits the
count to the budget: more points than ``budget - cfg.random_points`` are subsampled without
replacement; fewer are topped up by resampling points with replacement and jittering the copies'
positions by N(0, (0.5 spacing)^2) per axis (colour, time, velocity and spacing kept).
``cfg.random_points`` extra points (part of the budget) are uniform in pixel and depth in [near,
far] of random training cameras, with random colour, zero velocity, a time uniform over the keyframe
span and their own kNN spacing. All randomness comes from ``np.random.default_rng(seed)``.

``InitPoints.stats`` says what the set is made of (ftgspp/init/quality.py). Scene scale (depth
priors, fallbacks): median distance of the training camera centres to their centroid, or 1.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ftgspp.config import InitConfig
from ftgspp.data.scene import Camera, Scene
from ftgspp.errors import InputError
from ftgspp.init.dense import (
    AGREEMENT_MAX,
    COVERAGE_MIN,
    check_option,
    dense_trusted,
    sift_depth_gaps,
    triangulate_keyframe_dense,
)
from ftgspp.init.quality import depth_error, init_stats, velocity_error
from ftgspp.init.spacing import knn_spacing, union_spacing
from ftgspp.init.two_view import (
    fundamental_matrix,
    neighbor_pairs,
    pixel_colors,
    sampson_distance,
    triangulate_pair,
)
from ftgspp.init.velocity import check_velocity_mode, keyframe_velocities

log = logging.getLogger("ftgspp.init")

AUTO_MARGIN = (0.5, 1.5)  # "auto" with scene bounds: (near * 0.5, far * 1.5)
BASELINE_RANGE = (0.1, 1000.0)  # "auto" without bounds: multiples of the camera baseline
PRIORS = {"indoor": (0.2, 20.0), "outdoor": (0.5, 500.0)}  # multiples of the scene scale


@dataclass
class InitPoints:
    """Initial point set; every array has leading dimension N."""

    means: np.ndarray  # [N, 3] float32 world positions
    colors: np.ndarray  # [N, 3] float32 RGB in [0, 1]
    times: np.ndarray  # [N] float32 temporal centres mu_t in seconds (already jittered)
    velocities: np.ndarray  # [N, 3] float32 world units / second
    spacing: np.ndarray  # [N] float32 mean distance to 3 nearest neighbours (same keyframe)
    union_spacing: np.ndarray  # [N] float32 RMS distance to 3 nearest among every keyframe's points (spacing.py)
    keyframe: np.ndarray  # [N] int64 index of the keyframe the point came from
    stats: dict = field(default_factory=dict)  # what it is made of (ftgspp/init/quality.py); not per point

    def __len__(self) -> int:
        return len(self.means)

    def take(self, idx: np.ndarray) -> "InitPoints":
        """The points at ``idx`` (any integer index array, repeats allowed)."""
        return InitPoints(*(getattr(self, f)[idx] for f in POINT_FIELDS))


POINT_FIELDS = ("means", "colors", "times", "velocities", "spacing", "union_spacing", "keyframe")


# --------------------------------------------------------------------------- geometry


def scene_scale(scene: Scene) -> float:
    """Median distance of the training camera centres to their centroid (1 if zero)."""
    centers = np.stack([scene.cameras[i].center for i in scene.train_ids])  # [C, 3]
    scale = float(np.median(np.linalg.norm(centers - centers.mean(axis=0), axis=1)))
    return scale if scale > 0 else 1.0


def camera_baseline(scene: Scene) -> float:
    """Median distance of each training camera to its nearest training camera (1 if zero)."""
    centers = np.stack([scene.cameras[i].center for i in scene.train_ids])  # [C, 3]
    if len(centers) < 2:
        return 1.0
    d, _ = cKDTree(centers).query(centers, k=2)
    baseline = float(np.median(d[:, 1]))
    return baseline if baseline > 0 else 1.0


def depth_range(scene: Scene, cfg: InitConfig) -> tuple[float, float]:
    """(near, far) camera-space depth bounds for accepting triangulated points.

    ``auto``: the scene's near/far widened to (0.5 near, 1.5 far) when the format provides
    them, else (0.1, 1000) x camera baseline; ``indoor``: (0.2, 20) x scene scale;
    ``outdoor``: (0.5, 500) x scene scale; ``explicit``: ``cfg.near``, ``cfg.far``.
    """
    prior = cfg.depth_prior
    if prior == "auto":
        if scene.near is not None and scene.far is not None:
            near, far = scene.near * AUTO_MARGIN[0], scene.far * AUTO_MARGIN[1]
        else:
            b = camera_baseline(scene)
            near, far = BASELINE_RANGE[0] * b, BASELINE_RANGE[1] * b
    elif prior in PRIORS:
        s = scene_scale(scene)
        near, far = PRIORS[prior][0] * s, PRIORS[prior][1] * s
    elif prior == "explicit":
        if cfg.near is None or cfg.far is None:
            raise InputError("init.near/init.far", "depth_prior=explicit needs both init.near and init.far")
        near, far = float(cfg.near), float(cfg.far)
    else:
        expected = "auto, indoor, outdoor or explicit"
        raise InputError("init.depth_prior", f"unknown value {prior!r}; expected {expected}")
    if not (0 < near < far):
        raise InputError("init.near/init.far", f"need 0 < near < far, got near={near:g}, far={far:g}")
    return float(near), float(far)


# --------------------------------------------------------------------------- matching


@dataclass
class _View:
    pix: np.ndarray  # [n, 2] keypoints in the image (distorted) pixel coordinates
    loc: np.ndarray  # [n] location id: SIFT repeats a keypoint per orientation at one position
    und: np.ndarray  # [n, 2] the same keypoints undistorted (pinhole model)
    desc: np.ndarray | None  # [n, 128] float32 SIFT descriptors
    image: np.ndarray  # [H, W, 3] uint8 RGB


def _detect(sift: cv2.SIFT, cam: Camera, image: np.ndarray) -> _View:
    image = np.ascontiguousarray(image)
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    kps, desc = sift.detectAndCompute(gray, None)
    pix = np.array([kp.pt for kp in kps], dtype=np.float64).reshape(-1, 2)
    und = pix
    if cam.dist is not None and len(pix) and np.any(np.asarray(cam.dist) != 0):
        und = cv2.undistortPoints(pix.reshape(-1, 1, 2), cam.K, np.asarray(cam.dist), P=cam.K).reshape(-1, 2)
    _, loc = np.unique(pix, axis=0, return_inverse=True)
    return _View(pix, loc.reshape(-1), und, desc, image)


def _ratio_matches(desc_a: np.ndarray | None, desc_b: np.ndarray | None, ratio: float) -> np.ndarray:
    """[M, 2] keypoint index pairs passing Lowe's ratio test, one-to-one."""
    if desc_a is None or desc_b is None or len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(desc_a, desc_b, k=2)
    m = np.array(
        [(p[0].queryIdx, p[0].trainIdx) for p in knn if len(p) == 2 and p[0].distance < ratio * p[1].distance],
        dtype=np.int64,
    ).reshape(-1, 2)
    # drop b-keypoints claimed by several a-keypoints (ambiguous)
    _, inv, counts = np.unique(m[:, 1], return_inverse=True, return_counts=True)
    return m[counts[inv] == 1]


def _first_occurrence(ids: np.ndarray) -> np.ndarray:
    """Boolean mask [M] that is True at the first occurrence of each value of ids [M]."""
    mask = np.zeros(len(ids), dtype=bool)
    mask[np.unique(ids, return_index=True)[1]] = True
    return mask


def sift_pair_matches(scene: Scene, frame: int, cfg: InitConfig, near: float, far: float, exclusive: bool = True
                      ) -> tuple[list, dict]:
    """The kept SIFT matches of loaded frame ``frame``, per camera pair in ``neighbor_pairs`` order:
    ``(a, b, pix_a [m, 2] (image pixels of a), X [m, 3], colours [m, 3])``, and the counts
    (``views``, ``pairs``, ``matches``, ``epipolar``). Training cameras only; the pipeline and checks
    of the module docstring (``exclusive=False``: every pair keeps its matches, also of features an
    earlier pair used)."""
    sift = cv2.SIFT_create(nfeatures=cfg.max_features)
    pairs = neighbor_pairs(scene, cfg.neighbor_cams)
    cams = sorted({c for p in pairs for c in p})  # training cameras only
    views = {c: _detect(sift, scene.cameras[c], scene.frames(c)[frame]) for c in cams}
    used = {c: np.zeros(len(v.pix), dtype=bool) for c, v in views.items()}  # by location id
    out = []
    counts = dict(views=len(views), pairs=len(pairs), matches=0, epipolar=0)
    for a, b in pairs:
        va, vb, cam_a, cam_b = views[a], views[b], scene.cameras[a], scene.cameras[b]
        m = _ratio_matches(va.desc, vb.desc, cfg.ratio_test)
        if exclusive:
            m = m[~used[a][va.loc[m[:, 0]]] & ~used[b][vb.loc[m[:, 1]]]]
        counts["matches"] += len(m)
        pa, pb = va.und[m[:, 0]], vb.und[m[:, 1]]
        ok = sampson_distance(fundamental_matrix(cam_a, cam_b), pa, pb) < cfg.max_reproj_px
        m, pa, pb = m[ok], pa[ok], pb[ok]
        counts["epipolar"] += len(m)
        if len(m) == 0:
            continue
        X, keep = triangulate_pair(cam_a, cam_b, pa, pb, near, far, cfg.max_reproj_px)
        m, X = m[keep], X[keep]
        unique = _first_occurrence(va.loc[m[:, 0]]) & _first_occurrence(vb.loc[m[:, 1]])
        m, X = m[unique], X[unique]
        used[a][va.loc[m[:, 0]]] = True
        used[b][vb.loc[m[:, 1]]] = True
        colors = 0.5 * (pixel_colors(va.image, va.pix[m[:, 0]]) + pixel_colors(vb.image, vb.pix[m[:, 1]]))
        out.append((a, b, va.pix[m[:, 0]], X, colors))
    return out, counts


def triangulate_keyframe(
    scene: Scene, frame: int, cfg: InitConfig, near: float, far: float
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulated points [M, 3] and colours [M, 3] (float32) of loaded frame ``frame``.

    Uses training cameras only. See the module docstring for the pipeline and checks.
    """
    per_pair, counts = sift_pair_matches(scene, frame, cfg, near, far)
    points, colors = [X for *_, X, _ in per_pair], [c for *_, c in per_pair]
    P = np.concatenate(points).astype(np.float32) if points else np.zeros((0, 3), np.float32)
    C = np.concatenate(colors).astype(np.float32) if colors else np.zeros((0, 3), np.float32)
    log.info(
        "init: frame %d: %d views, %d pairs, %d matches, %d epipolar inliers, %d points",
        frame, counts["views"], counts["pairs"], counts["matches"], counts["epipolar"], len(P),
    )
    return P, C


# --------------------------------------------------------------------------- assembly


def keyframes(scene: Scene, cfg: InitConfig) -> list[int]:
    """Keyframe indices into the loaded frame range: 0, stride, 2 stride, ..."""
    if cfg.keyframe_stride < 1:
        raise InputError("init.keyframe_stride", f"must be >= 1, got {cfg.keyframe_stride}")
    return list(range(0, scene.n_frames, cfg.keyframe_stride))


def _random_points(scene: Scene, n: int, near: float, far: float, rng: np.random.Generator) -> np.ndarray:
    """n world points uniform in (pixel, depth) inside random training cameras' frusta. [n, 3]"""
    out = np.zeros((n, 3))
    cams = rng.integers(0, len(scene.train_ids), size=n)
    for ci in np.unique(cams):
        sel = cams == ci
        cam, m = scene.cameras[scene.train_ids[ci]], int(sel.sum())
        uv1 = np.stack(
            [rng.uniform(-0.5, cam.width - 0.5, m), rng.uniform(-0.5, cam.height - 0.5, m), np.ones(m)], axis=1
        )  # [m, 3]
        xc = (uv1 @ np.linalg.inv(cam.K).T) * rng.uniform(near, far, m)[:, None]  # camera space, z in [near, far]
        out[sel] = (xc - cam.T) @ cam.R  # R^T (xc - T)
    return out


def _fit_budget(pts: InitPoints, budget: int, rng: np.random.Generator) -> InitPoints:
    """Exactly ``budget`` points: subsample without replacement, or resample with replacement
    and jitter the copies' positions by N(0, (0.5 spacing)^2) per axis."""
    n = len(pts)
    if n >= budget:
        return pts.take(np.sort(rng.choice(n, size=budget, replace=False)))
    extra = pts.take(rng.integers(0, n, size=budget - n))
    jitter = rng.normal(size=extra.means.shape) * (0.5 * extra.spacing[:, None])  # [budget - n, 3]
    extra.means = (extra.means + jitter).astype(np.float32)
    return InitPoints(*(np.concatenate([getattr(pts, f), getattr(extra, f)]) for f in POINT_FIELDS))


def initialize(scene: Scene, cfg: InitConfig, budget: int, seed: int) -> InitPoints:
    """Exactly ``budget`` initial points (means, colours, times, velocities, spacing, keyframe).

    Raises ``InputError`` on bad options or when no point could be triangulated.
    """
    if budget < 1:
        raise InputError("budget", f"must be >= 1, got {budget}")
    n_random = int(cfg.random_points)
    if n_random < 0 or n_random >= budget:
        raise InputError("init.random_points", f"must be in [0, budget), got {n_random} with budget {budget}")
    rng = np.random.default_rng(seed)
    check_velocity_mode(cfg)  # fail before the expensive matching
    if cfg.matcher == "known":  # the control: a known-size scene's true Gaussians, perturbed (ftgspp/init/known.py)
        from ftgspp.init.known import true_points

        pts = _fit_budget(truth := InitPoints(**true_points(scene, cfg, rng)), budget, rng)  # fitted as matched points
        pts.stats = init_stats([len(truth)], budget, cfg.matcher)
        return pts
    near, far = depth_range(scene, cfg)
    kfs = keyframes(scene, cfg)
    kf_times = [float(scene.times[f]) for f in kfs]
    check = check_option(cfg)
    seen = None
    if cfg.matcher == "dense":
        tri, gaps, coverages = [], [], []
        for f in kfs:
            flows: dict = {}  # this keyframe's dense flows, for the check only
            P, C, counts = triangulate_keyframe_dense(scene, f, cfg, near, far, flows=flows, measure_coverage=True)
            tri.append((P, C))
            coverages.append(counts["coverage"])
            if check != "off":
                sift = sift_pair_matches(scene, f, cfg, near, far, exclusive=False)[0]
                gaps.append(sift_depth_gaps(scene, [(a, b, pix, X) for a, b, pix, X, _ in sift], flows))
        trusted, seen = dense_trusted(cfg, coverages, gaps)
        if not trusted:
            sift_tri = [triangulate_keyframe(scene, f, cfg, near, far) for f in kfs]
            why = (f"coverage of the views {seen['coverage']:.2f}, needs {COVERAGE_MIN:.2f}; median depth gap to SIFT"
                   f" {seen.get('disagreement', float('nan')):.3f}, at most {AGREEMENT_MAX:.2f}; init.dense_check={check}")
            if sum(len(p) for p, _ in sift_tri):
                log.info("init: dense points not trusted (%s): SIFT matches instead", why)
                tri = sift_tri
            else:  # SIFT + fill needs SIFT points: with none, the dense points are the only start there is
                log.info("init: dense points not trusted (%s), but SIFT triangulates no point: dense points kept", why)
                trusted = True
    else:
        tri = [triangulate_keyframe(scene, f, cfg, near, far) for f in kfs]
    points = [p for p, _ in tri]
    if sum(len(p) for p in points) == 0:
        raise InputError(
            scene.root,
            f"no points could be triangulated from {len(scene.train_ids)} training cameras at "
            f"{len(kfs)} keyframes (depth range {near:g}..{far:g}); check the calibration, "
            "init.depth_prior or init.near/init.far",
        )
    velocities = keyframe_velocities(points, kf_times, cfg)  # kNN: the result, or the flow's fallback
    spacing = [knn_spacing(p.astype(np.float64)) for p in points]
    if cfg.velocity == "flow":
        from ftgspp.init.flow_velocity import keyframe_flow_velocities

        velocities, _ = keyframe_flow_velocities(scene, kfs, points, velocities, spacing, cfg)
    stats = init_stats([len(p) for p in points], budget - n_random, cfg.matcher)
    # the stride in the clip's own terms (secret 3): how many keyframes, how many seconds apart
    stats["init_keyframes"] = float(len(kfs))
    stats["init_keyframe_interval_s"] = float(kf_times[1] - kf_times[0]) if len(kfs) > 1 else float(scene.duration)
    if seen is not None:
        stats["init_dense_coverage"] = seen["coverage"]
        if "disagreement" in seen:
            stats["init_dense_sift_disagreement"] = seen["disagreement"]
        stats["init_dense_fallback"] = float(not trusted)
    stats.update(velocity_error(scene, kfs, points, velocities))
    stats.update(depth_error(scene, kfs, points))
    all_spacing = np.concatenate(spacing)
    finite = all_spacing[np.isfinite(all_spacing)]
    fallback = float(np.median(finite)) if len(finite) else 0.01 * scene_scale(scene)
    floor = max(1e-4 * fallback, 1e-12)  # coincident points: keep scales strictly positive
    all_spacing = np.maximum(np.where(np.isfinite(all_spacing), all_spacing, fallback), floor)
    union = np.concatenate(union_spacing([p.astype(np.float64) for p in points]))  # floored by its own rule
    union = np.where(np.isfinite(union), union, fallback)

    half = cfg.keyframe_stride / scene.fps / 2.0
    keyframe = np.concatenate([np.full(len(p), i, dtype=np.int64) for i, p in enumerate(points)])
    times = np.asarray(kf_times)[keyframe] + rng.uniform(-half, half, size=len(keyframe))
    pts = InitPoints(
        means=np.concatenate(points).astype(np.float32),
        colors=np.concatenate([c for _, c in tri]).astype(np.float32),
        times=times.astype(np.float32),
        velocities=np.concatenate(velocities).astype(np.float32),
        spacing=all_spacing.astype(np.float32),
        union_spacing=union.astype(np.float32),
        keyframe=keyframe,
    )
    pts = _fit_budget(pts, budget - n_random, rng)
    if n_random:
        t0, t1 = kf_times[0] - half, kf_times[-1] + half
        rt = rng.uniform(t0, t1, size=n_random)
        rk = np.abs(rt[:, None] - np.asarray(kf_times)[None]).argmin(axis=1)
        rand_means = _random_points(scene, n_random, near, far, rng)
        rand_spacing = knn_spacing(rand_means)
        (rand_union,) = union_spacing([rand_means])
        rand = InitPoints(
            means=rand_means.astype(np.float32),
            colors=rng.uniform(0, 1, size=(n_random, 3)).astype(np.float32),
            times=rt.astype(np.float32),
            velocities=np.zeros((n_random, 3), np.float32),
            spacing=np.where(np.isfinite(rand_spacing), rand_spacing, fallback).astype(np.float32),
            union_spacing=np.where(np.isfinite(rand_union), rand_union, fallback).astype(np.float32),
            keyframe=rk.astype(np.int64),
        )
        pts = InitPoints(*(np.concatenate([getattr(pts, f), getattr(rand, f)]) for f in POINT_FIELDS))
    log.info(
        "init: %d keyframes, %d triangulated points, %d random, %d after budget (seed %d)",
        len(kfs), len(all_spacing), n_random, len(pts), seed,
    )
    pts.stats = stats
    return pts
