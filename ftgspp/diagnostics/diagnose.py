"""Diagnostics behind the paper's secrets, run on a trained model: the runner and ``ftgspp diagnose``.

``run_diagnostics`` writes one PNG per diagnostic and ``diagnostics.json``, and returns the
numbers as a ``DiagnosticsResult`` (``.metrics()``: the names a training run logs them under):

- lifetime histogram of Δt/T and **group renders**: the full render next to renders of only
  the short-lived (Δt/T < split) and only the long-lived Gaussians, and the histogram's
  **dip test** (``lifetime_dip``, ``lifetime_dip_p``, ``lifetime_dip_excess``: secret 1's
  "distinct short- and long-lived groups") (``lifetimes``);
- **velocity map** shown like optical flow (hue = direction, value = speed) next to the RGB
  render, **x–t slice** of ground truth (noise-free where the scene has ``gt/clean/``) and
  render, its arrays kept in ``xt_slice.npz`` (written with or without figures), and on
  scenes with ``gt/`` the **motion error** (``motion``);
- on scenes with ``gt/``, **scores against the ground-truth masks** (``scores``):
  ``lifetime_partition_contrast`` (secret 1), ``motion_role_switch`` (secret 2) and
  ``flicker_static`` (secret 4), from ``ground_truth_scores``; against the noise-free frames
  ``flicker_static_gt`` and ``flicker_static_excess``; on scenes drawn from known Gaussians
  (``gt/gaussians.npz``, ``truth``) the truth's own ``motion_role_switch_gt`` and
  ``motion_role_switch_excess`` = model − truth.

The figures are drawn by ``figures``. Run on a finished training run
(``config.json`` + ``gaussians.pt``)::

    ftgspp diagnose outputs/demo [--out DIR] [--theta 0.05] [--frame F] [--camera cam00]

or call ``run_diagnostics(model, scene, cfg, out_dir)`` after training.
"""

from __future__ import annotations

import argparse
import json
import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ftgspp.config import TrainConfig
from ftgspp.data.scene import Scene
from ftgspp.diagnostics.lifetimes import (
    drawn_in_clip,
    lifetime_dip,
    lifetime_fractions,
    lifetime_histogram,
    lifetime_vs_objects,
    mask_weights,
    partition_scores,
    role_switch_score,
    subset_model,
)
from ftgspp.diagnostics.motion import (
    ALPHA_MIN,
    GroundTruth,
    load_clean_frames,
    load_ground_truth,
    render_frames,
    scene_motion_error,
    static_flicker,
    velocity_map,
    xt_slice,
)
from ftgspp.diagnostics.truth import load_true_model
from ftgspp.errors import InputError
from ftgspp.evaluate import HeldOutRenders
from ftgspp.methods.base import DynamicGaussians

log = logging.getLogger("ftgspp.diagnostics")


def ground_truth_scores(model: DynamicGaussians, scene: Scene, cam: int, gt: GroundTruth, short: np.ndarray,
                        frames: np.ndarray, backend: str = "auto", truth: DynamicGaussians | None = None,
                        clean: np.ndarray | None = None) -> dict[str, float]:
    """Partition, role-switch and flicker scores of ``model`` in camera ``cam`` over every
    loaded frame; ``short [N]`` marks the short-lived Gaussians, ``frames [F, H, W, 3]`` the
    renders. Keys are the names the trainer logs them under.

    ``truth``: the scene's true Gaussians as a model (``truth.load_true_model``), scored the
    same way (``motion_role_switch_gt``, and the model's excess over it). ``clean``: the
    camera's noise-free frames, uint8 ``[F, H, W, 3]`` (``motion.load_clean_frames``), the
    reference of ``flicker_static_gt`` and ``flicker_static_excess``; the flicker of the
    recorded frames (sensor noise, codec) is ``flicker_static_gt_noisy`` either way."""
    def masks(f: int) -> np.ndarray:  # moving objects, static pixels (, transient objects)
        m = [gt.objects[f] > 0, gt.objects[f] == 0]
        return np.stack(m if gt.transient is None else [*m, gt.transient[f]])

    per_frame = [mask_weights(model, scene.cameras[cam], float(t), masks(f), backend)
                 for f, t in enumerate(scene.times)]
    w = np.stack(per_frame)  # [F, N, 2 or 3]
    part = partition_scores(w[..., 0].sum(axis=0), w[..., 1].sum(axis=0), short)
    flicker = static_flicker(frames, gt.objects)
    gt_frames = scene.frames(cam).astype(np.float32) / 255.0
    switch = role_switch_score(w[..., 0])
    scores = {
        "lifetime_partition_contrast": part["partition_contrast"],
        "lifetime_short_share_dynamic": part["short_share_dynamic"],
        "lifetime_short_share_static": part["short_share_static"],
        "motion_role_switch": switch,
        "flicker_static": flicker["flicker"],
        "flicker_static_gt_noisy": static_flicker(gt_frames, gt.objects)["flicker"],
    }
    if clean is not None:  # the reference without sensor noise and codec: what a perfect render would score
        scores["flicker_static_gt"] = static_flicker(clean.astype(np.float32) / 255.0, gt.objects)["flicker"]
        scores["flicker_static_excess"] = scores["flicker_static"] - scores["flicker_static_gt"]
    if truth is not None:  # the level of "no role switching": the true Gaussians through the same scoring
        w_true = np.stack([mask_weights(truth, scene.cameras[cam], float(t), (gt.objects[f] > 0)[None], backend)[:, 0]
                           for f, t in enumerate(scene.times)])  # [F, K]
        scores["motion_role_switch_gt"] = role_switch_score(w_true)
        scores["motion_role_switch_excess"] = switch - scores["motion_role_switch_gt"]
    if gt.transient is not None and gt.transient.any():  # content that exists for part of the clip
        split = partition_scores(w[..., 2].sum(axis=0), w[..., 1].sum(axis=0), short)
        scores["lifetime_short_share_transient"] = split["short_share_dynamic"]
        scores["lifetime_transient_contrast"] = split["partition_contrast"]
    return scores


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
            "lifetime_dip": self.lifetime.get("dip"),
            "lifetime_dip_p": self.lifetime.get("dip_p"),
            "lifetime_dip_excess": self.lifetime.get("dip_excess"),
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
    model: DynamicGaussians,
    scene: Scene,
    cfg: TrainConfig,
    out_dir: str | Path,
    theta: float = 0.05,
    frame: int | None = None,
    camera: int | None = None,
    split: float = 0.5,
    row: int | None = None,
    backend: str | None = None,
    figures: bool = True,
    renders: HeldOutRenders | None = None,
) -> DiagnosticsResult:
    """Write every diagnostic PNG and ``diagnostics.json`` into ``out_dir``; return the numbers.

    ``camera`` (index into ``scene.cameras``) defaults to the first test camera, ``frame``
    to the middle frame, ``row`` (x–t slice) to the middle image row. ``motion`` and
    ``scores`` are measured on scenes with ground truth only. ``figures=False`` measures the
    same numbers and writes only ``diagnostics.json`` (drawing is most of the time).
    ``renders``: evaluation's renders (``HeldOutRenders``), reused where they are the same views.
    """
    from ftgspp.diagnostics import figures as plots  # the parameter `figures` is the switch

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
    if renders is not None and not renders.matches(model, scene, sh, bg, backend):
        renders = None

    def frames_at(ids: list[int]) -> np.ndarray:  # renders of camera cam_i, [F, H, W, 3] float32
        if renders is None:
            return render_frames(model, cam, scene.times[ids], sh, bg, backend)
        return np.stack([renders.image(cam_i, f).cpu().numpy() for f in ids]).astype(np.float32)

    def draw(name: str, plot: Callable[..., Path], *args: object) -> None:
        if figures:
            files[name] = plot(*args)

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
    dip = lifetime_dip(frac, drawn_in_clip(model, theta, scene.times))
    lifetime["n_drawn"] = dip["n"]
    if dip["n"] > 3:  # the dip test is not defined below 4 values: left out
        lifetime.update(dip=dip["dip"], dip_p=dip["p"], dip_critical=dip["critical"], dip_excess=dip["excess"])
    draw("lifetime_histogram", plots.plot_lifetime_histogram,
         counts, edges, frac, split, theta, scene.duration, out / "lifetime_histogram.png")

    # group renders (a figure only)
    if figures:
        groups = {"all Gaussians": np.ones(len(frac), bool), f"short-lived (Δt/T < {split:g})": frac < split,
                  f"long-lived (Δt/T ≥ {split:g})": frac >= split}  # fmt: skip
        group_images = {}
        for name, keep in groups.items():
            sub = subset_model(model, keep)
            group_images[f"{name}: {int(keep.sum())}"] = render_frames(sub, cam, np.array([t]), sh, bg, backend)[0]
        files["lifetime_groups"] = plots.plot_group_renders(scene.image(cam_i, frame), group_images, where,
                                                            out / "lifetime_groups.png")

    # velocity map
    flow, alpha = velocity_map(model, cam, t, scene.fps, backend)
    if figures:
        rgb = frames_at([frame])[0]
        files["velocity_map"] = plots.plot_velocity_map(rgb, flow, alpha > ALPHA_MIN, where, out / "velocity_map.png")
    speed = np.linalg.norm(flow, axis=-1)[alpha > ALPHA_MIN]
    velocity = {"mean": float(speed.mean()) if speed.size else 0.0,
                "p99": float(np.percentile(speed, 99)) if speed.size else 0.0}

    # x–t slice: against the noise-free frames where the scene has them (the arrays are kept either way)
    recorded_xt = xt_slice(scene.frames(cam_i), row)  # uint8 [F, W, 3]
    gt_xt = recorded_xt.astype(np.float32) / 255.0
    clean = load_clean_frames(scene, cam_i)
    clean_xt = None if clean is None else xt_slice(clean, row)
    all_frames = frames_at(list(range(scene.n_frames)))  # [F, H, W, 3]
    render_xt = xt_slice(all_frames, row)
    files["xt_slice_arrays"] = save_xt_arrays(out / "xt_slice.npz", render_xt, recorded_xt, clean_xt, row, cam.name,
                                              scene.fps)
    ref_xt, ref_name = (gt_xt, "ground truth") if clean_xt is None else (clean_xt / 255.0, "noise-free ground truth")
    draw("xt_slice", plots.plot_xt_slice, ref_xt, render_xt, cam.name, row, scene.fps, out / "xt_slice.png", ref_name)
    result = DiagnosticsResult(camera=cam.name, frame=frame, theta=theta, split=split, row=row, lifetime=lifetime,
                               velocity_px_per_frame=velocity, xt_slice_mae=float(np.abs(gt_xt - render_xt).mean()),
                               files=files)  # fmt: skip

    # ground truth: motion error and where the lifetime groups lie
    gt = load_ground_truth(scene, cam_i)
    if gt is not None:
        motion, maps = scene_motion_error(model, scene, cam_i, gt, backend=backend)
        result.motion = motion
        v, a = maps[frame]
        draw("motion_error", plots.plot_motion_error,
             v, a > ALPHA_MIN, gt.flow3d[frame], gt.objects[frame], motion, where, out / "motion_error.png")
        gts = {cam_i: gt}
        for c in scene.train_ids:
            g = load_ground_truth(scene, c)
            if g is not None:
                gts[c] = g
        lifetime.update(lifetime_vs_objects(model, scene, gts, frac, split))
        truth = load_true_model(scene, model.params["means"].device)
        result.scores = ground_truth_scores(model, scene, cam_i, gt, frac < split, all_frames, backend, truth=truth,
                                            clean=clean)

    (out / "diagnostics.json").write_text(json.dumps(result.as_json(), indent=2))
    files["json"] = out / "diagnostics.json"
    log.info("diagnostics of %s in %s: %d short-lived, %d long-lived Gaussians%s", cam.name, out,
             lifetime["n_short_lived"], lifetime["n_long_lived"],
             "; motion EPE %.4f, static leak %.4f" % (motion["epe_dynamic"], motion["leak_static"])
             if gt is not None else "")  # fmt: skip
    return result


def save_xt_arrays(path: Path, render: np.ndarray, recorded: np.ndarray, clean: np.ndarray | None, row: int,
                   camera: str, fps: float) -> Path:
    """``xt_slice.npz``: the x–t slice arrays the figure draws, for reports that compare runs
    (``harness/report/xt_figures.py``): ``render`` float16 ``[F, W, 3]`` in [0, 1], ``gt`` the
    recorded frames' slice and, where the scene has them, ``gt_clean`` the noise-free frames'
    (uint8 ``[F, W, 3]``), ``row``, ``camera`` and ``fps``."""
    arrays = {"render": np.asarray(render, dtype=np.float16), "gt": np.asarray(recorded, dtype=np.uint8),
              "row": np.int64(row), "camera": np.str_(camera), "fps": np.float64(fps)}
    if clean is not None:
        arrays["gt_clean"] = np.asarray(clean, dtype=np.uint8)
    np.savez_compressed(path, **arrays)
    return path


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

    from ftgspp.checkpoint import load_run, run_scene

    model, cfg = load_run(args.run_dir)
    scene = run_scene(cfg, args.data)
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
