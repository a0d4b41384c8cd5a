"""Flow-guided initial velocities (FreeTimeGS++, docs/design.md §4, "Init").

For the points ``X [M, 3]`` of keyframe ``frame0`` and the next keyframe ``frame1``:

1. every training camera c: project X (camera depth z), sample the forward flow and the
   forward-backward covisibility weight (``ftgspp.init.flow``) at the projection
   (bilinear), move the pixel by the flow and back-project it at the same depth z. The
   3D displacement ``d_c`` this gives lies in camera c's constant-depth plane: a single
   view cannot see motion along its own optical axis ``a_c``.
2. views are combined with covisibility weights ``w_c`` = fb weight × in image × in front
   (× optionally a point-cloud visibility test, below). ``combine="mean"`` (default) is the
   paper's weighted average ``Σ w_c d_c / Σ w_c``. ``combine="lsq"`` solves the
   weighted least squares ``min_d Σ w_c |P_c (d − d_c)|²`` with ``P_c = I − a_c a_cᵀ``,
   i.e. it only asks each view for the components it can see; directions no view
   constrains (one shared optical axis, a forward-facing rig) are damped to zero by a
   Tikhonov term ``λ = 0.1 Σ w_c``. When every view shares one axis the two agree; on the
   50° arc of the synthetic ``studio`` rig lsq is ~4 % better on moving points and ~35 %
   worse on static ones (noise along the weakly seen depth axis), so ``mean`` is default.
   ``combine="rays"`` recovers the full 3D displacement: each view's flow moves the point's
   pixel, the ray through the moved pixel must pass through the moved point, and the point
   nearest all views' moved rays (weighted least squares, ``combine_rays``) is the point one
   flow step later — triangulated, so motion along a view's axis is seen by the others.
3. v = d / Δt with Δt = t(frame1) − t(frame0) (negative when looking backwards from the
   last keyframe). Accepted where ``Σ w_c ≥ min_weight`` and ``|v| |Δt| ≤ 3 × spacing``
   (local kNN spacing); elsewhere the kNN velocity is kept.

Occlusion: on real data there is no depth, so a point hidden in a view is only down-weighted
by the fb weight where its occluder moves differently from it (the default). ``occlusion=True``
adds a visibility test against the point cloud itself: in each view, a point is hidden when
another point of the set projects into the same ``CELL_PX`` cell more than
``OCCLUSION_MARGIN × spacing`` nearer to the camera (on ``studio`` it lowers the static
points' error by ~15 % and leaves moving points unchanged; off by default because outlier
points floating in front of a surface would hide it).

    vel, accepted, stats = flow_velocities(scene, pts, 0, 10, knn_vel, spacing, get_flow_model("dis"))
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ftgspp.config import InitConfig
from ftgspp.data.scene import Camera, Scene
from ftgspp.init.flow import FlowModel, FlowSet, get_flow_model, keyframe_flows, sample_bilinear

log = logging.getLogger("ftgspp.init.flow")

MIN_WEIGHT = 1.0  # total covisibility weight (sum over views) needed to trust the flow velocity
MAX_DISP_FACTOR = 3.0  # |v| dt <= factor * local kNN spacing
DAMPING = 0.1  # Tikhonov weight (x total weight) for directions no view constrains
RAY_DAMPING = 0.01  # the same for combine="rays" (a ray's projector is well conditioned across views)
CELL_PX = 4  # occlusion test: z-buffer cell size in pixels
OCCLUSION_MARGIN = 2.0  # ... and depth margin in units of the point's kNN spacing


def view_displacements(
    cam: Camera, points: np.ndarray, flow_fw: np.ndarray, weight: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One view's 3D displacements of ``points [M, 3]`` from its flow.

    Returns ``(d [M, 3], w [M], z [M])``: back-projected displacement at constant camera
    depth, covisibility weight (fb weight sampled at the projection, 0 when behind the
    camera or outside the image) and camera depth.
    """
    xc = points @ cam.R.T + cam.T  # [M, 3]
    z = xc[:, 2]
    front = z > 1e-9
    zs = np.where(front, z, 1.0)
    uv = (xc @ cam.K.T)[:, :2] / zs[:, None]  # [M, 2]
    flow, inside = sample_bilinear(flow_fw, uv)  # [M, 2]
    w, _ = sample_bilinear(weight[..., None], uv)
    w = np.where(front & inside, w[:, 0], 0.0)
    uv1 = np.hstack([uv + flow, np.ones((len(uv), 1))])  # [M, 3]
    xc1 = (uv1 @ np.linalg.inv(cam.K).T) * zs[:, None]  # same depth
    d = (xc1 - xc) @ cam.R  # camera -> world: R^T (xc1 - xc)
    return np.where(w[:, None] > 0, d, 0.0), w, z


def visible_mask(cam: Camera, points: np.ndarray, spacing: np.ndarray, cell_px: int = CELL_PX,
                 margin: float = OCCLUSION_MARGIN) -> np.ndarray:
    """``[M]`` False where another point of ``points`` in the same image cell is nearer by
    more than ``margin × spacing`` (a z-buffer of the point cloud in ``cam``)."""
    xc = points @ cam.R.T + cam.T
    z = xc[:, 2]
    ok = z > 1e-9
    uv = (xc @ cam.K.T)[:, :2] / np.where(ok, z, 1.0)[:, None]
    nx, ny = cam.width // cell_px + 1, cam.height // cell_px + 1
    cx = np.floor((uv[:, 0] + 0.5) / cell_px).astype(np.int64)
    cy = np.floor((uv[:, 1] + 0.5) / cell_px).astype(np.int64)
    ok &= (cx >= 0) & (cx < nx) & (cy >= 0) & (cy < ny)
    cell = np.where(ok, cy * nx + cx, 0)
    zmin = np.full(nx * ny, np.inf)
    np.minimum.at(zmin, cell[ok], z[ok])
    return ~ok | (z <= zmin[cell] + margin * spacing)


def combine_views(
    disp: np.ndarray, weights: np.ndarray, axes: np.ndarray, combine: str = "mean", damping: float = DAMPING
) -> np.ndarray:
    """Per-point 3D displacement ``[M, 3]`` from per-view ones.

    disp ``[C, M, 3]``, weights ``[C, M]``, axes ``[C, 3]`` (unit optical axes in world).
    ``mean``: weighted average; ``lsq``: damped weighted least squares (module docstring).
    """
    wsum = weights.sum(axis=0)  # [M]
    b = np.einsum("cm,cmk->mk", weights, disp)  # [M, 3]
    if combine == "mean":
        return b / np.maximum(wsum, 1e-12)[:, None]
    if combine != "lsq":
        raise ValueError(f"combine must be 'lsq' or 'mean', got {combine!r}")
    proj = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]  # [C, 3, 3]
    A = np.einsum("cm,cij->mij", weights, proj)  # [M, 3, 3]
    e, U = np.linalg.eigh(A)  # ascending eigenvalues, [M, 3], [M, 3, 3]
    lam = damping * wsum[:, None]
    gain = e / np.maximum(e * e + lam * lam, 1e-24)  # Tikhonov-filtered inverse
    coef = np.einsum("mik,mi->mk", U, b) * gain  # components along eigenvectors
    return np.einsum("mik,mk->mi", U, coef)


def moved_rays(cam: Camera, points: np.ndarray, flow_fw: np.ndarray) -> np.ndarray:
    """Unit world rays ``[M, 3]`` from ``cam``'s centre through each point's pixel moved by the flow:
    where the view sees the point one flow step later (any depth along it)."""
    xc = points @ cam.R.T + cam.T
    zs = np.where(xc[:, 2] > 1e-9, xc[:, 2], 1.0)
    uv = (xc @ cam.K.T)[:, :2] / zs[:, None]
    flow, _ = sample_bilinear(flow_fw, uv)
    ray = (np.hstack([uv + flow, np.ones((len(uv), 1))]) @ np.linalg.inv(cam.K).T) @ cam.R  # R^T K^-1 [u, 1]
    return ray / np.linalg.norm(ray, axis=1, keepdims=True)


def combine_rays(points: np.ndarray, centers: np.ndarray, rays: np.ndarray, weights: np.ndarray,
                 damping: float = RAY_DAMPING) -> np.ndarray:
    """Full 3D displacement ``[M, 3]``: the moved point X + d nearest (weighted least squares) to
    every view's moved ray, ``min_d Σ_c w_c |(I − r_c r_cᵀ)(X + d − C_c)|²`` — the point
    triangulated one flow step later, so depth components are kept wherever two views' rays
    differ in direction. centers ``[C, 3]``, rays ``[C, M, 3]``, weights ``[C, M]``. Directions no
    pair of rays constrains are damped toward no motion (Tikhonov, ``damping × Σ w``).
    """
    proj = np.eye(3)[None, None] - rays[..., :, None] * rays[..., None, :]  # [C, M, 3, 3]
    A = np.einsum("cm,cmij->mij", weights, proj)  # [M, 3, 3]
    b = np.einsum("cm,cmij,cmj->mi", weights, proj, centers[:, None, :] - points[None])  # [M, 3]
    e, U = np.linalg.eigh(A)
    lam = damping * weights.sum(axis=0)[:, None]
    gain = e / np.maximum(e * e + lam * lam, 1e-24)
    return np.einsum("mik,mk->mi", U, np.einsum("mik,mi->mk", U, b) * gain)


def flow_velocities(
    scene: Scene,
    points: np.ndarray,  # [M, 3]
    frame0: int,
    frame1: int,
    knn_vel: np.ndarray,  # [M, 3]
    spacing: np.ndarray,  # [M]
    flow_model: FlowModel,
    cache_dir: str | Path | None = None,
    flows: FlowSet | None = None,
    min_weight: float = MIN_WEIGHT,
    max_disp_factor: float = MAX_DISP_FACTOR,
    combine: str = "mean",
    occlusion: bool = False,
) -> tuple[np.ndarray, np.ndarray, dict]:
    """Flow-guided velocities of keyframe ``frame0``'s points toward ``frame1`` (loaded indices).

    Returns ``(velocities [M, 3] float32, accepted [M] bool, stats)``; rejected points keep
    ``knn_vel``. ``flows`` (from ``keyframe_flows``) skips the flow computation.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    knn = np.asarray(knn_vel, dtype=np.float64).reshape(-1, 3)
    spacing = np.asarray(spacing, dtype=np.float64).reshape(-1)
    dt = float(scene.times[frame1] - scene.times[frame0])
    if dt == 0:
        raise ValueError("flow_velocities: frame0 and frame1 have the same time")
    if flows is None:
        flows = keyframe_flows(scene, frame0, frame1, flow_model, cache_dir)
    cams = sorted(flows.forward)
    m = len(pts)
    disp = np.zeros((len(cams), m, 3))
    weights = np.zeros((len(cams), m))
    axes = np.zeros((len(cams), 3))
    rays = np.zeros((len(cams), m, 3)) if combine == "rays" else None
    for k, c in enumerate(cams):
        cam = scene.cameras[c]
        disp[k], weights[k], _ = view_displacements(cam, pts, flows.forward[c], flows.weight(c))
        if occlusion and m:
            weights[k] *= visible_mask(cam, pts, spacing)
        axes[k] = cam.R[2]  # camera z axis in world coordinates
        if rays is not None:
            rays[k] = moved_rays(cam, pts, flows.forward[c])
    wsum = weights.sum(axis=0)
    if not m:
        vel = np.zeros((0, 3))
    elif rays is not None:
        vel = combine_rays(pts, np.stack([scene.cameras[c].center for c in cams]), rays, weights) / dt
    else:
        vel = combine_views(disp, weights, axes, combine) / dt
    speed_ok = np.linalg.norm(vel, axis=1) * abs(dt) <= max_disp_factor * spacing
    weight_ok = wsum >= min_weight
    accepted = weight_ok & speed_ok & np.all(np.isfinite(vel), axis=1)
    out = np.where(accepted[:, None], vel, knn).astype(np.float32)
    stats = {
        "n_points": m,
        "n_accepted": int(accepted.sum()),
        "accepted_fraction": float(accepted.mean()) if m else 0.0,
        "n_low_weight": int((~weight_ok).sum()),
        "n_too_far": int((weight_ok & ~speed_ok).sum()),
        "mean_views": float((weights > 0.5).sum(axis=0).mean()) if m else 0.0,
        "flow_compute_s": flows.timings.get("compute_s", 0.0),
        "flow_load_s": flows.timings.get("load_s", 0.0),
    }
    log.info(
        "flow velocity frames %d->%d: %d/%d accepted (%d low covisibility, %d too far), %.1f views/point",
        frame0, frame1, stats["n_accepted"], m, stats["n_low_weight"], stats["n_too_far"], stats["mean_views"],
    )
    return out, accepted, stats


def keyframe_flow_velocities(
    scene: Scene,
    keyframes: list[int],
    points: list[np.ndarray],  # per keyframe [M_i, 3]
    knn_velocities: list[np.ndarray],  # per keyframe [M_i, 3]
    spacing: list[np.ndarray],  # per keyframe [M_i]
    cfg: InitConfig,
    cache_dir: str | Path | None = None,
) -> tuple[list[np.ndarray], dict]:
    """``flow_velocities`` for every keyframe, paired like ``keyframe_velocities``.

    Keyframe i looks at i+1; the last one looks back at i-1 (negative Δt); a single
    keyframe keeps its kNN velocities. Returns per-keyframe velocities and summed stats.
    """
    model = get_flow_model(getattr(cfg, "flow_model", "dis"))
    n = len(keyframes)
    out, total = [], {"n_points": 0, "n_accepted": 0, "flow_compute_s": 0.0, "flow_load_s": 0.0}
    for i in range(n):
        if n == 1:
            out.append(np.asarray(knn_velocities[i], dtype=np.float32))
            continue
        j = i + 1 if i + 1 < n else i - 1
        a, b = sorted((keyframes[i], keyframes[j]))
        flows = keyframe_flows(scene, a, b, model, cache_dir)  # one cached pair per interval
        if j < i:  # looking backwards: swap the roles of the two flows
            flows = FlowSet(keyframes[i], keyframes[j], flows.backward, flows.forward, flows.timings)
        vel, _, st = flow_velocities(
            scene, points[i], keyframes[i], keyframes[j], knn_velocities[i], spacing[i], model, flows=flows,
            min_weight=getattr(cfg, "flow_min_weight", MIN_WEIGHT),
            max_disp_factor=getattr(cfg, "flow_max_disp", MAX_DISP_FACTOR),
            combine=getattr(cfg, "flow_combine", "mean"),
        )  # fmt: skip
        out.append(vel)
        for k in total:
            total[k] += st[k]
    total["accepted_fraction"] = total["n_accepted"] / max(total["n_points"], 1)
    log.info(
        "flow velocity: %d/%d points accepted; flow time %.2f s computed, %.2f s loaded from cache",
        total["n_accepted"], total["n_points"], total["flow_compute_s"], total["flow_load_s"],
    )
    return out, total
