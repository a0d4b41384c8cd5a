"""What an initialisation is made of, and, on a synthetic scene, how right its velocities are.

``init_stats`` counts the real (triangulated) points per keyframe and the share they fill of the
budget left after ``init.random_points`` (the rest of it is jittered copies). ``velocity_error`` scores the initial velocities
against the scene's ground truth (``gt/depth`` and ``gt/flow3d``): each real point of keyframe
f is looked up in the first training camera that sees it (its projected depth within
``DEPTH_TOL`` of the ground-truth depth at its pixel: the visible surface is the point), and
its velocity is compared with the ground-truth world velocity there. Points on moving content
(true speed above ``MOVING_SPEED``) and on static content are scored apart: the median
end-point error in units/s, and on moving points also the median true speed, so the error
reads as a fraction of the motion.

``depth_error`` scores the initial points' positions against the true depth (``gt/depth``, read at
its own resolution, whatever ``data.downsample`` the run trains at): a point's relative depth
error is ``|z - d| / d`` in the training camera where that is smallest, ``z`` its depth in the
camera and ``d`` the true depth at the pixel it projects to (a point on a surface some camera
sees scores about 0 there; a point in free space or behind a surface scores the gap).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ftgspp.data.scene import Scene
from ftgspp.init.two_view import project

log = logging.getLogger("ftgspp.init")

DEPTH_TOL = 0.02  # relative depth agreement that counts as "this camera sees the point"
MOVING_SPEED = 1e-3  # units/s: slower ground truth counts as static


def init_stats(per_keyframe: list[int], budget: int, matcher: str) -> dict[str, float]:
    """Real points per keyframe (min / median / max), their total and share of the budget."""
    n = np.asarray(per_keyframe, dtype=np.float64)
    total = float(n.sum())
    return {
        "init_matcher_dense": float(matcher == "dense"),
        "init_points_total": total,
        "init_points_per_keyframe_min": float(n.min()) if len(n) else 0.0,
        "init_points_per_keyframe_median": float(np.median(n)) if len(n) else 0.0,
        "init_points_per_keyframe_max": float(n.max()) if len(n) else 0.0,
        "init_real_share": min(total, budget) / budget if budget else 0.0,
    }


def ground_truth_velocities(scene: Scene, keyframes: list[int], points: list[np.ndarray]
                            ) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Per keyframe: the world velocity ``[M, 3]`` of each point at that frame and a mask ``[M]``
    of the points some training camera sees (NaN velocity elsewhere); None without ground truth.
    One camera's ground truth is loaded at a time."""
    from ftgspp.diagnostics.motion import load_ground_truth  # diagnostics read the same files

    out = [(np.full((len(p), 3), np.nan), np.zeros(len(p), dtype=bool)) for p in points]
    for cam_id in scene.train_ids:
        gt = load_ground_truth(scene, cam_id)
        if gt is None:
            return None
        cam = scene.cameras[cam_id]
        for f, p, (vel, found) in zip(keyframes, points, out):
            uv, z = project(cam, np.asarray(p, dtype=np.float64))
            with np.errstate(invalid="ignore"):
                x, y = np.rint(uv[:, 0]), np.rint(uv[:, 1])
                inside = (~found) & (z > 0) & (x >= 0) & (x < cam.width) & (y >= 0) & (y < cam.height)
            xi, yi = x[inside].astype(np.int64), y[inside].astype(np.int64)
            seen = np.abs(gt.depth[f][yi, xi] - z[inside]) < DEPTH_TOL * z[inside]
            idx = np.flatnonzero(inside)[seen]
            vel[idx] = gt.flow3d[f][yi[seen], xi[seen]]
            found[idx] = True
    return out


def velocity_error(scene: Scene, keyframes: list[int], points: list[np.ndarray],
                   velocities: list[np.ndarray]) -> dict[str, float]:
    """Median initial-velocity error on moving and static points (empty without ground truth, or
    when the ground-truth files cannot be read: a warning, never a failed run)."""
    if scene.ground_truth is None:
        return {}
    try:
        truth = ground_truth_velocities(scene, keyframes, points)
    except (OSError, ValueError, IndexError) as exc:
        log.warning("init: ground truth of %s unreadable (%s); initial velocities not scored", scene.root, exc)
        return {}
    if truth is None or not sum(int(found.sum()) for _, found in truth):
        return {}
    gt = np.concatenate([vel[found] for vel, found in truth])
    v = np.concatenate([np.asarray(est, dtype=np.float64)[found] for est, (_, found) in zip(velocities, truth)])
    speed, err = np.linalg.norm(gt, axis=1), np.linalg.norm(v - gt, axis=1)
    moving = speed > MOVING_SPEED
    out = {"init_velocity_points_scored": float(len(gt))}
    if moving.any():
        out["init_velocity_error_moving"] = float(np.median(err[moving]))
        out["init_velocity_true_speed_moving"] = float(np.median(speed[moving]))
    if (~moving).any():
        out["init_velocity_error_static"] = float(np.median(err[~moving]))
    return out


def relative_depth_errors(scene: Scene, frame: int, points: np.ndarray) -> np.ndarray | None:
    """``[M]`` relative depth error of each point of loaded frame ``frame`` (``inf`` where no training
    camera sees it in its image); None without ``gt/depth`` files for every training camera."""
    if scene.ground_truth is None:
        return None
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    best = np.full(len(P), np.inf)
    for cam_id in scene.train_ids:
        cam = scene.cameras[cam_id]
        path = Path(scene.ground_truth) / "depth" / f"{cam.name}.npy"
        if not path.is_file():
            return None
        truth = np.load(path, mmap_mode="r")[int(scene.frame_ids[frame])]  # [H', W'] at the written size
        full = cam.scaled(truth.shape[1] / cam.width) if truth.shape[1] != cam.width else cam
        uv, z = project(full, P)
        with np.errstate(invalid="ignore"):
            x, y = np.rint(uv[:, 0]), np.rint(uv[:, 1])
            inside = (z > 0) & (x >= 0) & (x < truth.shape[1]) & (y >= 0) & (y < truth.shape[0])
        d = np.asarray(truth)[y[inside].astype(np.int64), x[inside].astype(np.int64)].astype(np.float64)
        idx = np.flatnonzero(inside)
        best[idx] = np.minimum(best[idx], np.abs(z[inside] - d) / np.maximum(d, 1e-12))
    return best


def depth_error(scene: Scene, keyframes: list[int], points: list[np.ndarray]) -> dict[str, float]:
    """Median and 90th percentile of the real points' relative depth error over every keyframe
    (empty without ground truth, or when its files cannot be read: a warning, never a failed run)."""
    if scene.ground_truth is None or not sum(len(p) for p in points):
        return {}
    try:
        errs = [relative_depth_errors(scene, f, p) for f, p in zip(keyframes, points)]
    except (OSError, ValueError, IndexError) as exc:
        log.warning("init: ground-truth depth of %s unreadable (%s); initial points not scored", scene.root, exc)
        return {}
    if any(e is None for e in errs):
        return {}
    e = np.concatenate(errs)
    return {"init_depth_error_median": float(np.median(e)),
            "init_depth_error_p90": float(np.quantile(e, 0.9, method="inverted_cdf"))}
