"""Motion and time in a trained model: image-plane velocities, composited maps, x–t slices,
and its motion against a synthetic scene's ground truth.

- **Velocity map**: each Gaussian's 3D velocity projected to the image (Jacobian of the
  pinhole projection at its mean, pixels per frame), alpha-composited like a colour.
- **x–t slice**: one image row of a camera stacked over all frames (rows = time), where
  relocation wobble shows as jagged edges.
- **Motion error** (scenes with ``gt/``): the composited 3D velocity (world units/s, divided
  by alpha where alpha > ``ALPHA_MIN``) against ``gt/flow3d``: mean end-point error on moving
  objects (``gt/objects > 0``) and the mean speed leaking into static regions.
- **Static flicker** (secret 4): temporal std of the rendered colour on pixels static for
  the whole clip, against the same measure on the held-out camera's noise-free frames
  (``gt/clean/<cam>.npy``: the frames before sensor noise and video coding, which a
  synthetic scene writes for its test camera; ``load_clean_frames``).

    flow, alpha = velocity_map(model, cam, t, fps)        # [H, W, 2] px/frame, [H, W]
    gt = load_ground_truth(scene, cam_index)              # None without gt/
    clean = load_clean_frames(scene, cam_index)           # uint8 [F, H, W, 3], None without gt/clean/
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from ftgspp.data.scene import Camera, Scene
from ftgspp.methods.base import DynamicGaussians
from ftgspp.view import render_view

ALPHA_MIN = 0.5  # composited quantities are trusted where alpha > this


# --------------------------------------------------------------------------- velocities


def pixel_velocities(model: DynamicGaussians, cam: Camera, t: float) -> torch.Tensor:
    """Image-plane velocity of every Gaussian's centre at time ``t``, px/s, ``[N, 2]``.

    d/dt (fx x/z + cx, fy y/z + cy) with camera-space position p = R μ(t) + T and ṗ = R μ'(t)
    (the method's ``at_time`` and ``velocities_at``).
    """
    dev = model.params["means"].device
    R = torch.as_tensor(cam.R, dtype=torch.float32, device=dev)
    T = torch.as_tensor(cam.T, dtype=torch.float32, device=dev)
    with torch.no_grad():
        mu = model.at_time(t).means  # [N, 3]
        p = mu @ R.T + T  # [N, 3]
        pdot = model.velocities_at(t) @ R.T  # [N, 3]
        z = p[:, 2].clamp_min(1e-6)
        fx, fy = float(cam.K[0, 0]), float(cam.K[1, 1])
        du = fx * (pdot[:, 0] * z - p[:, 0] * pdot[:, 2]) / z**2
        dv = fy * (pdot[:, 1] * z - p[:, 1] * pdot[:, 2]) / z**2
        return torch.stack([du, dv], dim=-1)


def composite(model: DynamicGaussians, cam: Camera, t: float, values: torch.Tensor, backend: str = "auto"
              ) -> tuple[np.ndarray, np.ndarray]:
    """Alpha-composite per-Gaussian ``values [N, D]``: ``(image / alpha [H, W, D], alpha [H, W])``,
    the normalised image being 0 where alpha <= ``ALPHA_MIN``."""
    with torch.no_grad():
        out, _ = render_view(model, cam, t, 0, background=None, backend=backend, colors=values.float())
    img = out.image.detach().cpu().numpy().astype(np.float64)
    alpha = out.alpha[..., 0].detach().cpu().numpy().astype(np.float64)
    ok = alpha > ALPHA_MIN
    return np.where(ok[..., None], img / np.where(ok, alpha, 1.0)[..., None], 0.0), alpha


def velocity_map(model: DynamicGaussians, cam: Camera, t: float, fps: float, backend: str = "auto"
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Composited image-plane velocity in px/frame ``[H, W, 2]`` and alpha ``[H, W]``."""
    return composite(model, cam, t, pixel_velocities(model, cam, t) / fps, backend)


# --------------------------------------------------------------------------- x–t slices


def xt_slice(frames: np.ndarray, row: int) -> np.ndarray:
    """Row ``row`` of every frame: ``frames [F, H, W, C] -> [F, W, C]`` (time down)."""
    return np.ascontiguousarray(np.asarray(frames)[:, row])


def render_frames(model: DynamicGaussians, cam: Camera, times: np.ndarray, sh_degree: int,
                  background: torch.Tensor | None = None, backend: str = "auto") -> np.ndarray:
    """RGB renders at every time, float32 ``[F, H, W, 3]`` in [0, 1]."""
    out = []
    with torch.no_grad():
        for t in times:
            r, _ = render_view(model, cam, float(t), sh_degree, background=background, backend=backend)
            out.append(r.image.clamp(0, 1).cpu().numpy())
    return np.stack(out).astype(np.float32)


# --------------------------------------------------------------------------- ground truth and motion error


@dataclass
class GroundTruth:
    """Per-camera ground truth of a synthetic scene at the camera's resolution."""

    depth: np.ndarray  # [F, H, W] float32 camera z-depth
    flow3d: np.ndarray  # [F, H, W, 3] float32 world velocity of the visible point, units/s
    objects: np.ndarray  # [F, H, W] uint8 or uint16 object labels, 0 = static background
    transient: np.ndarray | None = None  # [F, H, W] bool: an object that exists for part of the clip


def nearest_indices(src: int, dst: int) -> np.ndarray:
    """Source index of each of ``dst`` samples when resizing ``src`` samples to ``dst`` by
    nearest neighbour: ``cv2.resize``'s ``INTER_NEAREST`` rule, floor(i * src / dst) with the
    scale taken as 1 / (dst / src) in float64, so a gather gives its pixels exactly."""
    return np.minimum(np.floor(np.arange(dst) * (1.0 / (dst / src))).astype(np.int64), src - 1)


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
    transient = Path(scene.ground_truth) / "transient" / f"{c.name}.npy"
    if transient.is_file():
        paths.append(transient)
    arrays = []
    for p in paths:
        a = np.asarray(np.load(p, mmap_mode="r")[ids])
        if a.shape[1:3] != (c.height, c.width):  # a nearest-neighbour resize is a gather: no per-frame copies
            a = a.take(nearest_indices(a.shape[1], c.height), axis=1).take(nearest_indices(a.shape[2], c.width), axis=2)
        arrays.append(a)
    objects = arrays[2] if arrays[2].dtype in (np.uint8, np.uint16) else arrays[2].astype(np.uint16)
    return GroundTruth(arrays[0].astype(np.float32), arrays[1].astype(np.float32), objects,
                       arrays[3] > 0 if len(arrays) > 3 else None)


CLEAN_DIR = "clean"  # gt/clean/<cam>.npy: noise-free frames of the held-out camera


def load_clean_frames(scene: Scene, cam: int) -> np.ndarray | None:
    """``gt/clean/<cam>.npy`` (uint8 RGB ``[F, H, W, 3]``, the camera's frames before sensor noise
    and video coding) cut to the loaded frames and brought to the camera's resolution as the
    loader brings the video (``cv2.INTER_AREA``), so it lines up with ``scene.frames(cam)``;
    None when the scene has no such file."""
    if scene.ground_truth is None:
        return None
    c = scene.cameras[cam]
    path = Path(scene.ground_truth) / CLEAN_DIR / f"{c.name}.npy"
    if not path.is_file():
        return None
    frames = np.asarray(np.load(path, mmap_mode="r")[np.asarray(scene.frame_ids)])
    if frames.shape[1:3] == (c.height, c.width):
        return frames
    return np.stack([cv2.resize(f, (c.width, c.height), interpolation=cv2.INTER_AREA) for f in frames])


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


def scene_motion_error(model: DynamicGaussians, scene: Scene, cam: int, gt: GroundTruth,
                       frames: list[int] | None = None, backend: str = "auto") -> tuple[dict, dict]:
    """``motion_error`` of ``model`` in camera ``cam`` pooled over ``frames`` (default all),
    and per-frame maps ``{frame: (velocity [H, W, 3], alpha [H, W])}``."""
    frames = list(range(scene.n_frames)) if frames is None else frames
    maps = {}
    for f in frames:
        t = float(scene.times[f])
        maps[f] = composite(model, scene.cameras[cam], t, model.velocities_at(t).detach(), backend)
    v = np.stack([maps[f][0] for f in frames])
    a = np.stack([maps[f][1] for f in frames])
    return motion_error(v, a, gt.flow3d[frames], gt.objects[frames]), maps


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
