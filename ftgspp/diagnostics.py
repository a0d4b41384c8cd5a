"""Diagnostics behind the paper's secrets: lifetimes, group renders, velocity maps, x–t
slices and (on synthetic scenes) motion error against ground-truth scene flow.

- **Effective lifetime** Δt(θ)/T of every Gaussian: how long its rendered opacity stays
  above θ, over the scene duration T. Without the gate this is ``model.lifetimes(θ)``; with
  it, φ(t) = g + (1 − g) a(t) ≥ θ/o needs a(t) ≥ a* = (θ/o − g)/(1 − g), so
  Δt = 2 s √(2 log(1/a*)), and a Gaussian with o·g ≥ θ is visible forever (Δt = ∞).
- **Group renders**: the full render next to renders of only the short-lived (Δt/T <
  split) and only the long-lived Gaussians.
- **Velocity map**: each Gaussian's 3D velocity projected to the image (Jacobian of the
  pinhole projection at its mean, pixels per frame), alpha-composited like a colour and
  shown like optical flow (hue = direction, value = speed) next to the RGB render.
- **x–t slice**: one image row of a camera stacked over all frames (rows = time), ground
  truth and render, where relocation wobble shows as jagged edges.
- **Motion error** (scenes with ``gt/``): the composited 3D velocity (world units/s,
  divided by alpha where alpha > 0.5) against ``gt/flow3d``: mean end-point error on
  moving objects (``gt/objects > 0``) and the mean speed leaking into static regions.
- **Scores against the ground-truth masks** (``result["scores"]``, named like the metrics
  the trainer logs): ``lifetime_partition_contrast`` (secret 1: share of the rendered
  weight on moving-object pixels carried by short-lived Gaussians minus that share on
  static pixels; 1 = perfect split), ``motion_role_switch`` (secret 2: how much the set of
  Gaussians rendering the moving objects changes from frame to frame, 0 = the same
  Gaussians throughout, 1 = a disjoint set every frame) and ``flicker_static`` (secret 4:
  temporal std of the rendered colour on pixels static for the whole clip).

Run on a finished training run (``config.json`` + ``gaussians.pt``)::

    ftgspp diagnose outputs/demo [--out DIR] [--theta 0.05] [--frame F] [--camera cam00]

or call ``run_diagnostics(model, scene, cfg, out_dir)`` after training.
"""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from ftgspp.config import TrainConfig
from ftgspp.data.scene import Camera, Scene
from ftgspp.diagnostics_colors import color_wheel, flow_to_rgb  # noqa: F401  (re-exported)
from ftgspp.errors import InputError
from ftgspp.model import FreeTimeGaussians
from ftgspp.view import render_view

log = logging.getLogger("ftgspp.diagnostics")

ALPHA_MIN = 0.5  # composited quantities are trusted where alpha > this


# --------------------------------------------------------------------------- lifetimes


def effective_lifetimes(model: FreeTimeGaussians, theta: float) -> torch.Tensor:
    """Effective lifetime Δt(θ) in seconds, ``[N]`` (``inf`` for gated Gaussians that never fade)."""
    with torch.no_grad():
        return model.lifetimes(theta)


def lifetime_fractions(model: FreeTimeGaussians, theta: float, duration: float) -> np.ndarray:
    """Δt(θ)/T for every Gaussian, ``[N]`` float64 (``inf`` where it never fades)."""
    return effective_lifetimes(model, theta).detach().cpu().double().numpy() / float(duration)


def lifetime_histogram(fractions: np.ndarray, bins: int = 40, max_fraction: float = 2.0
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``(counts [bins], edges [bins + 1])`` of Δt/T on [0, max_fraction]; larger values
    (and ``inf``) are counted in the last bin."""
    return np.histogram(np.minimum(fractions, max_fraction), bins=bins, range=(0.0, max_fraction))


def subset_model(model: FreeTimeGaussians, keep: np.ndarray | torch.Tensor) -> FreeTimeGaussians:
    """A model with only the Gaussians where ``keep [N]`` is True (parameters copied)."""
    keep = torch.as_tensor(keep, dtype=torch.bool, device=model.params["means"].device)
    return FreeTimeGaussians({k: v.detach()[keep] for k, v in model.params.items()}, model.cfg)


# --------------------------------------------------------------------------- velocities


def pixel_velocities(model: FreeTimeGaussians, cam: Camera, t: float) -> torch.Tensor:
    """Image-plane velocity of every Gaussian's centre at time ``t``, px/s, ``[N, 2]``.

    d/dt (fx x/z + cx, fy y/z + cy) with camera-space position p = R μ(t) + T and ṗ = R v.
    """
    p_ = model.params
    dev = p_["means"].device
    R = torch.as_tensor(cam.R, dtype=torch.float32, device=dev)
    T = torch.as_tensor(cam.T, dtype=torch.float32, device=dev)
    with torch.no_grad():
        mu = p_["means"] + p_["velocities"] * (t - p_["times"])[:, None]  # [N, 3]
        p = mu @ R.T + T  # [N, 3]
        pdot = p_["velocities"] @ R.T  # [N, 3]
        z = p[:, 2].clamp_min(1e-6)
        fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
        du = fx * (pdot[:, 0] * z - p[:, 0] * pdot[:, 2]) / z**2
        dv = fy * (pdot[:, 1] * z - p[:, 1] * pdot[:, 2]) / z**2
        return torch.stack([du, dv], dim=-1)


def composite(model: FreeTimeGaussians, cam: Camera, t: float, values: torch.Tensor, backend: str = "auto"
              ) -> tuple[np.ndarray, np.ndarray]:
    """Alpha-composite per-Gaussian ``values [N, D]``: ``(image / alpha [H, W, D], alpha [H, W])``,
    the normalised image being 0 where alpha <= ``ALPHA_MIN``."""
    with torch.no_grad():
        out, _ = render_view(model, cam, t, 0, background=None, backend=backend, colors=values.float())
    img = out.image.detach().cpu().numpy().astype(np.float64)
    alpha = out.alpha[..., 0].detach().cpu().numpy().astype(np.float64)
    ok = alpha > ALPHA_MIN
    return np.where(ok[..., None], img / np.where(ok, alpha, 1.0)[..., None], 0.0), alpha


def velocity_map(model: FreeTimeGaussians, cam: Camera, t: float, fps: float, backend: str = "auto"
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Composited image-plane velocity in px/frame ``[H, W, 2]`` and alpha ``[H, W]``."""
    return composite(model, cam, t, pixel_velocities(model, cam, t) / fps, backend)


# --------------------------------------------------------------------------- x–t slices


def xt_slice(frames: np.ndarray, row: int) -> np.ndarray:
    """Row ``row`` of every frame: ``frames [F, H, W, C] -> [F, W, C]`` (time down)."""
    return np.ascontiguousarray(np.asarray(frames)[:, row])


def render_frames(model: FreeTimeGaussians, cam: Camera, times: np.ndarray, sh_degree: int,
                  background: torch.Tensor | None = None, backend: str = "auto") -> np.ndarray:
    """RGB renders at every time, float32 ``[F, H, W, 3]`` in [0, 1]."""
    out = []
    with torch.no_grad():
        for t in times:
            r, _ = render_view(model, cam, float(t), sh_degree, background=background, backend=backend)
            out.append(r.image.clamp(0, 1).cpu().numpy())
    return np.stack(out).astype(np.float32)


# --------------------------------------------------------------------------- motion error


@dataclass
class GroundTruth:
    """Per-camera ground truth of a synthetic scene at the camera's resolution."""

    depth: np.ndarray  # [F, H, W] float32 camera z-depth
    flow3d: np.ndarray  # [F, H, W, 3] float32 world velocity of the visible point, units/s
    objects: np.ndarray  # [F, H, W] uint8, 0 = static background


def load_ground_truth(scene: Scene, cam: int) -> GroundTruth | None:
    """``gt/{depth,flow3d,objects}/<cam>.npy`` cut to the loaded frames and resized
    (nearest) to the camera's resolution; None when the scene has no such files."""
    if scene.ground_truth is None:
        return None
    c = scene.cameras[cam]
    paths = [Path(scene.ground_truth) / sub / f"{c.name}.npy" for sub in ("depth", "flow3d", "objects")]
    if not all(p.is_file() for p in paths):
        return None
    ids = np.asarray(scene.frame_ids)
    arrays = []
    for p in paths:
        a = np.load(p, mmap_mode="r")[ids]
        if a.shape[1:3] != (c.height, c.width):
            a = np.stack([cv2.resize(np.asarray(x, dtype=np.float32), (c.width, c.height),
                                     interpolation=cv2.INTER_NEAREST) for x in a])  # fmt: skip
        arrays.append(np.asarray(a))
    return GroundTruth(arrays[0].astype(np.float32), arrays[1].astype(np.float32), arrays[2].astype(np.uint8))


def motion_error(velocity: np.ndarray, alpha: np.ndarray, gt_flow3d: np.ndarray, objects: np.ndarray,
                 alpha_min: float = ALPHA_MIN) -> dict[str, float]:
    """Motion error of a composited velocity image against ground-truth scene flow.

    velocity ``[..., H, W, 3]`` (already divided by alpha), alpha ``[..., H, W]``, gt
    ``[..., H, W, 3]``, objects ``[..., H, W]``. Returns ``epe_dynamic`` (mean |v − v_gt|
    over covered pixels on moving objects), ``leak_static`` (mean |v| over covered static
    pixels) and the pixel counts. Leading dimensions (e.g. frames) are pooled.
    """
    covered = alpha > alpha_min
    dyn, sta = covered & (objects > 0), covered & (objects == 0)
    epe = np.linalg.norm(velocity - gt_flow3d, axis=-1)
    speed = np.linalg.norm(velocity, axis=-1)
    return {
        "epe_dynamic": float(epe[dyn].mean()) if dyn.any() else float("nan"),
        "leak_static": float(speed[sta].mean()) if sta.any() else float("nan"),
        "gt_speed_dynamic": float(np.linalg.norm(gt_flow3d, axis=-1)[dyn].mean()) if dyn.any() else float("nan"),
        "n_dynamic_px": float(dyn.sum()),
        "n_static_px": float(sta.sum()),
    }


def scene_motion_error(model: FreeTimeGaussians, scene: Scene, cam: int, gt: GroundTruth,
                       frames: list[int] | None = None, backend: str = "auto") -> tuple[dict, dict]:
    """``motion_error`` of ``model`` in camera ``cam`` pooled over ``frames`` (default all),
    and per-frame maps ``{frame: (velocity [H, W, 3], alpha [H, W])}``."""
    frames = list(range(scene.n_frames)) if frames is None else frames
    vel = model.params["velocities"].detach()
    maps = {f: composite(model, scene.cameras[cam], float(scene.times[f]), vel, backend) for f in frames}
    v = np.stack([maps[f][0] for f in frames])
    a = np.stack([maps[f][1] for f in frames])
    return motion_error(v, a, gt.flow3d[frames], gt.objects[frames]), maps


def lifetime_vs_objects(model: FreeTimeGaussians, scene: Scene, gts: dict[int, GroundTruth],
                        fractions: np.ndarray, split: float, depth_tol: float = 0.05) -> dict[str, float]:
    """Where the long- and short-lived Gaussians lie, from ground-truth object masks.

    A Gaussian is classified in the first camera of ``gts`` where its centre, at its own
    time clipped to the loaded range (nearest frame), projects inside the image with a depth
    within ``depth_tol`` (relative) of the ground-truth depth there (i.e. on the visible
    surface); it is dynamic if the object mask is > 0 there.
    """
    p = {k: v.detach().cpu().double().numpy() for k, v in model.params.items()}
    times = scene.times
    frame = np.abs(np.clip(p["times"], times[0], times[-1])[:, None] - times[None]).argmin(axis=1)  # [N]
    mu = p["means"] + p["velocities"] * (times[frame] - p["times"])[:, None]
    label = np.full(len(mu), -1)  # -1 unclassified, 0 static, 1 dynamic
    for cam_i, gt in gts.items():
        cam = scene.cameras[cam_i]
        xc = mu @ cam.R.T + cam.T
        z = xc[:, 2]
        uv = (xc @ cam.K.T)[:, :2] / np.where(z > 1e-9, z, 1.0)[:, None]
        x, y = np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
        ok = (label < 0) & (z > 1e-9) & (x >= 0) & (x < cam.width) & (y >= 0) & (y < cam.height)
        xs, ys = np.where(ok, x, 0), np.where(ok, y, 0)
        d = gt.depth[frame, ys, xs]
        ok &= np.abs(z - d) <= depth_tol * d
        label[ok] = (gt.objects[frame, ys, xs] > 0)[ok].astype(np.int64)
    long_ = fractions >= split
    short = ~long_
    cl = label >= 0

    def frac(a: np.ndarray, b: np.ndarray) -> float:
        return float(a.sum() / b.sum()) if b.sum() else float("nan")

    return {
        "classified_fraction": float(cl.mean()) if len(cl) else float("nan"),
        "long_lived_on_static": frac(long_ & cl & (label == 0), long_ & cl),
        "short_lived_on_dynamic": frac(short & cl & (label == 1), short & cl),
        "dynamic_that_are_short_lived": frac(short & cl & (label == 1), cl & (label == 1)),
        "static_that_are_long_lived": frac(long_ & cl & (label == 0), cl & (label == 0)),
    }


# --------------------------------------------------------------------------- scores against ground-truth masks


def mask_weights(model: FreeTimeGaussians, cam: Camera, t: float, masks: np.ndarray, backend: str = "auto"
                 ) -> np.ndarray:
    """Rendered weight each Gaussian carries on each mask at time ``t``: ``[N, M]`` float64.

    ``masks [M, H, W]`` bool. Entry (i, m) is Σ over the pixels of mask m of Gaussian i's
    compositing weight T_i α_i, i.e. the gradient of the mask-summed render of all-ones
    colours with respect to Gaussian i's colour (one render and one backward pass).
    Column sums equal the rendered alpha summed over each mask.
    """
    masks = np.asarray(masks, dtype=bool)
    frozen = subset_model(model, np.ones(model.params["means"].shape[0], dtype=bool))  # no parameter gradients
    dev = frozen.params["means"].device
    ones = torch.ones(frozen.params["means"].shape[0], masks.shape[0], device=dev, requires_grad=True)
    out, _ = render_view(frozen, cam, t, 0, background=None, backend=backend, colors=ones)
    sel = torch.as_tensor(np.moveaxis(masks, 0, -1), dtype=out.image.dtype, device=dev)  # [H, W, M]
    (grad,) = torch.autograd.grad((out.image * sel).sum(), ones)
    return grad.detach().cpu().double().numpy()


def partition_scores(w_dynamic: np.ndarray, w_static: np.ndarray, short: np.ndarray) -> dict[str, float]:
    """Secret 1: how cleanly short-lived Gaussians render the moving content.

    ``w_dynamic [N]`` / ``w_static [N]``: each Gaussian's rendered weight on moving-object
    and on static pixels (``mask_weights``, summed over frames); ``short [N]`` bool. Returns
    the short-lived share of each and their difference ``partition_contrast`` in [-1, 1].
    """
    short = np.asarray(short, dtype=bool)

    def share(w: np.ndarray) -> float:
        total = float(np.sum(w))
        return float(np.sum(w[short]) / total) if total > 0 else float("nan")

    dyn, sta = share(np.asarray(w_dynamic, float)), share(np.asarray(w_static, float))
    return {"short_share_dynamic": dyn, "short_share_static": sta, "partition_contrast": dyn - sta}


def role_switch_score(weights: np.ndarray) -> float:
    """Secret 2: mean total-variation distance between consecutive frames' distributions of
    the weight on the moving objects over Gaussians, ``weights [F, N]`` -> [0, 1].

    0: the same Gaussians, in the same proportions, render the objects in every frame;
    1: every frame uses Gaussians the previous frame did not. Frames without weight are skipped.
    """
    w = np.asarray(weights, dtype=float)
    w = w[w.sum(axis=1) > 0]
    if len(w) < 2:
        return float("nan")
    p = w / w.sum(axis=1, keepdims=True)
    return float((0.5 * np.abs(np.diff(p, axis=0)).sum(axis=1)).mean())


def static_flicker(frames: np.ndarray, objects: np.ndarray) -> dict[str, float]:
    """Secret 4: temporal std of the colour over pixels static in every frame.

    ``frames [F, H, W, C]`` in [0, 1], ``objects [F, H, W]`` (0 = static). Per pixel the
    population std over frames, averaged over channels; returns its mean over the pixels
    whose mask is 0 throughout (``flicker``) and their count.
    """
    static = (np.asarray(objects) == 0).all(axis=0)  # [H, W]
    std = np.asarray(frames, dtype=np.float64).std(axis=0).mean(axis=-1)  # [H, W]
    return {"flicker": float(std[static].mean()) if static.any() else float("nan"),
            "n_static_px": float(static.sum())}


def ground_truth_scores(model: FreeTimeGaussians, scene: Scene, cam: int, gt: GroundTruth, short: np.ndarray,
                        frames: np.ndarray, backend: str = "auto") -> dict[str, float]:
    """Partition, role-switch and flicker scores of ``model`` in camera ``cam`` over every
    loaded frame; ``short [N]`` marks the short-lived Gaussians, ``frames [F, H, W, 3]`` the
    renders. Keys are the names the trainer logs them under."""
    per_frame = [mask_weights(model, scene.cameras[cam], float(t), np.stack([gt.objects[f] > 0, gt.objects[f] == 0]),
                              backend) for f, t in enumerate(scene.times)]  # fmt: skip
    w = np.stack(per_frame)  # [F, N, 2]
    part = partition_scores(w[..., 0].sum(axis=0), w[..., 1].sum(axis=0), short)
    flicker = static_flicker(frames, gt.objects)
    gt_frames = scene.frames(cam).astype(np.float32) / 255.0
    return {
        "lifetime_partition_contrast": part["partition_contrast"],
        "lifetime_short_share_dynamic": part["short_share_dynamic"],
        "lifetime_short_share_static": part["short_share_static"],
        "motion_role_switch": role_switch_score(w[..., 0]),
        "flicker_static": flicker["flicker"],
        "flicker_static_gt": static_flicker(gt_frames, gt.objects)["flicker"],
    }


# --------------------------------------------------------------------------- run + CLI


@dataclass
class DiagnosticsResult:
    """What ``run_diagnostics`` measured and the files it wrote (``diagnostics.json``: ``as_json()``)."""

    camera: str  # name of the camera of the single-camera plots
    frame: int
    theta: float  # opacity threshold of the effective lifetime
    split: float  # Δt/T separating short- from long-lived Gaussians
    row: int  # image row of the x–t slice
    lifetime: dict[str, float]  # group counts, median Δt/T; with ground truth, where the groups lie
    velocity_px_per_frame: dict[str, float]  # mean and p99 composited image speed
    xt_slice_mae: float
    motion: dict[str, float] | None = None  # motion error (scenes with ground truth)
    scores: dict[str, float] | None = None  # ground-truth scores, under the names they are logged
    files: dict[str, Path] = field(default_factory=dict)  # every PNG, and ``json``

    def metrics(self) -> dict[str, float]:
        """The numbers a training run logs, by metric name (a number not measured is left out)."""
        motion = self.motion or {}
        numbers = {
            "lifetime_long_on_static": self.lifetime.get("long_lived_on_static"),
            "lifetime_short_on_dynamic": self.lifetime.get("short_lived_on_dynamic"),
            "lifetime_median_fraction": self.lifetime.get("median_fraction"),
            "motion_epe_dynamic": motion.get("epe_dynamic"),
            "motion_leak_static": motion.get("leak_static"),
            "xt_slice_mae": self.xt_slice_mae,
            **(self.scores or {}),
        }
        return {k: float(v) for k, v in numbers.items() if v is not None}

    def as_json(self) -> dict:
        """The content of ``diagnostics.json`` (its own path left out of ``files``)."""
        out: dict = {"camera": self.camera, "frame": self.frame, "theta": self.theta, "split": self.split,
                     "row": self.row, "lifetime": self.lifetime, "velocity_px_per_frame": self.velocity_px_per_frame,
                     "xt_slice_mae": self.xt_slice_mae}  # fmt: skip
        if self.motion is not None:
            out["motion"] = self.motion
        if self.scores is not None:
            out["scores"] = self.scores
        out["files"] = {k: str(v) for k, v in self.files.items() if k != "json"}
        return out


def run_diagnostics(
    model: FreeTimeGaussians,
    scene: Scene,
    cfg: TrainConfig,
    out_dir: str | Path,
    theta: float = 0.05,
    frame: int | None = None,
    camera: int | None = None,
    split: float = 0.5,
    row: int | None = None,
    backend: str | None = None,
) -> DiagnosticsResult:
    """Write every diagnostic PNG and ``diagnostics.json`` into ``out_dir``; return the numbers.

    ``camera`` (index into ``scene.cameras``) defaults to the first test camera, ``frame``
    to the middle frame, ``row`` (x–t slice) to the middle image row. ``motion`` and
    ``scores`` are measured on scenes with ground truth only.
    """
    from ftgspp import diagnostics_plots as plots

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    backend = backend or cfg.backend
    cam_i = scene.test_ids[0] if camera is None else camera
    cam = scene.cameras[cam_i]
    frame = scene.n_frames // 2 if frame is None else frame
    if not 0 <= frame < scene.n_frames:
        raise InputError("--frame", f"must be in [0, {scene.n_frames}), got {frame}")
    row = cam.height // 2 if row is None else row
    t = float(scene.times[frame])
    sh = cfg.model.sh_degree
    bg = torch.tensor(cfg.background, dtype=torch.float32, device=model.params["means"].device)
    where = f"{cam.name}, frame {frame} (t = {t:.3f} s)"
    files: dict[str, Path] = {}

    # lifetimes
    frac = lifetime_fractions(model, theta, scene.duration)
    counts, edges = lifetime_histogram(frac)
    visible = frac > 0
    lifetime = {
        "n_gaussians": int(len(frac)),
        "n_never_visible": int((~visible).sum()),
        "n_short_lived": int((visible & (frac < split)).sum()),
        "n_long_lived": int((frac >= split).sum()),
        "n_persistent": int(np.isinf(frac).sum()),
        "median_fraction": float(np.median(frac)) if len(frac) else float("nan"),
    }
    files["lifetime_histogram"] = plots.plot_lifetime_histogram(
        counts, edges, frac, split, theta, scene.duration, out / "lifetime_histogram.png")

    # group renders
    gt_img = scene.image(cam_i, frame)
    groups = {"all Gaussians": np.ones(len(frac), bool), f"short-lived (Δt/T < {split:g})": frac < split,
              f"long-lived (Δt/T ≥ {split:g})": frac >= split}  # fmt: skip
    renders = {}
    for name, keep in groups.items():
        sub = subset_model(model, keep)
        renders[f"{name}: {int(keep.sum())}"] = render_frames(sub, cam, np.array([t]), sh, bg, backend)[0]
    files["lifetime_groups"] = plots.plot_group_renders(gt_img, renders, where, out / "lifetime_groups.png")

    # velocity map
    rgb = render_frames(model, cam, np.array([t]), sh, bg, backend)[0]
    flow, alpha = velocity_map(model, cam, t, scene.fps, backend)
    files["velocity_map"] = plots.plot_velocity_map(rgb, flow, alpha > ALPHA_MIN, where, out / "velocity_map.png")
    speed = np.linalg.norm(flow, axis=-1)[alpha > ALPHA_MIN]
    velocity = {"mean": float(speed.mean()) if speed.size else 0.0,
                "p99": float(np.percentile(speed, 99)) if speed.size else 0.0}

    # x–t slice
    gt_xt = xt_slice(scene.frames(cam_i), row).astype(np.float32) / 255.0
    all_frames = render_frames(model, cam, scene.times, sh, bg, backend)  # [F, H, W, 3]
    render_xt = xt_slice(all_frames, row)
    files["xt_slice"] = plots.plot_xt_slice(gt_xt, render_xt, cam.name, row, scene.fps, out / "xt_slice.png")
    result = DiagnosticsResult(camera=cam.name, frame=frame, theta=theta, split=split, row=row, lifetime=lifetime,
                               velocity_px_per_frame=velocity, xt_slice_mae=float(np.abs(gt_xt - render_xt).mean()),
                               files=files)  # fmt: skip

    # ground truth: motion error and where the lifetime groups lie
    gt = load_ground_truth(scene, cam_i)
    if gt is not None:
        motion, maps = scene_motion_error(model, scene, cam_i, gt, backend=backend)
        result.motion = motion
        v, a = maps[frame]
        files["motion_error"] = plots.plot_motion_error(
            v, a > ALPHA_MIN, gt.flow3d[frame], gt.objects[frame], motion, where, out / "motion_error.png")
        gts = {cam_i: gt}
        for c in scene.train_ids:
            g = load_ground_truth(scene, c)
            if g is not None:
                gts[c] = g
        lifetime.update(lifetime_vs_objects(model, scene, gts, frac, split))
        result.scores = ground_truth_scores(model, scene, cam_i, gt, frac < split, all_frames, backend)

    (out / "diagnostics.json").write_text(json.dumps(result.as_json(), indent=2))
    files["json"] = out / "diagnostics.json"
    log.info("diagnostics of %s in %s: %d short-lived, %d long-lived Gaussians%s", cam.name, out,
             lifetime["n_short_lived"], lifetime["n_long_lived"],
             "; motion EPE %.4f, static leak %.4f" % (motion["epe_dynamic"], motion["leak_static"])
             if gt is not None else "")  # fmt: skip
    return result


def main(argv: list[str] | None = None) -> int:
    """``ftgspp diagnose RUN_DIR [--out DIR] [--theta θ] [--frame F] [--camera NAME]``."""
    ap = argparse.ArgumentParser(prog="ftgspp diagnose", description=__doc__.split("\n\n")[0])
    ap.add_argument("run_dir", help="a finished training run (config.json + gaussians.pt)")
    ap.add_argument("--out", default=None, help="output folder (default RUN_DIR/diagnostics)")
    ap.add_argument("--theta", type=float, default=0.05, help="opacity threshold of the effective lifetime")
    ap.add_argument("--split", type=float, default=0.5, help="Δt/T separating short- from long-lived")
    ap.add_argument("--frame", type=int, default=None, help="frame of the single-frame plots (default middle)")
    ap.add_argument("--camera", default=None, help="camera name (default the first test camera)")
    ap.add_argument("--row", type=int, default=None, help="image row of the x–t slice (default middle)")
    ap.add_argument("--data", default=None, help="scene folder (default: data.path of the run's config)")
    ap.add_argument("--backend", default=None, help="render backend (default: the run's)")
    args = ap.parse_args(argv)
    if not 0 < args.theta < 1:
        raise InputError("--theta", f"must be in (0, 1), got {args.theta}")

    from ftgspp.checkpoint import load_run
    from ftgspp.data.load import load_scene

    model, cfg = load_run(args.run_dir)
    if args.data:
        cfg.data.path = args.data
    scene = load_scene(cfg.data)
    camera = None
    if args.camera is not None:
        names = [c.name for c in scene.cameras]
        if args.camera not in names:
            raise InputError("--camera", f"{args.camera!r} not in the scene (cameras: {', '.join(names)})")
        camera = names.index(args.camera)
    out = Path(args.out) if args.out else Path(args.run_dir) / "diagnostics"
    backend = args.backend or ("auto" if cfg.backend == "gsplat" else cfg.backend)
    res = run_diagnostics(model, scene, cfg, out, theta=args.theta, frame=args.frame, camera=camera,
                          split=args.split, row=args.row, backend=backend)  # fmt: skip
    for path in res.files.values():
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
