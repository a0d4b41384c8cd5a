"""``ftgspp synth``: procedural multi-view dynamic scenes with ground truth.

Renders a textured room (floor, ceiling, side walls, a back wall with a window onto a
far backdrop, two static props) and two moving textured spheres -- one on a straight
line, one on a circular arc while spinning -- seen by an arc of pinhole cameras
(``cam00`` in the middle is the test view). Each camera gets its own affine colour
shift and sensor noise, like a real rig. Output is written in the DyNeRF or the
EasyVolcap layout, or through a lens in the Immersive (fisheye) or ENeRF-Outdoor (distorted
EasyVolcap) layout (``layouts``), plus ground truth in ``<out>/gt/`` (depth, scene
flow, object masks, trajectories, colour transforms, and the held-out camera's frames before
sensor noise and video coding) so that motion and flicker can be scored.

Run::

    ftgspp synth --out data/synth_studio                       # DyNeRF layout
    ftgspp synth --out data/synth_fast --layout easyvolcap --preset fast_motion
    python -m ftgspp.data.synthetic --out /tmp/s --cameras 6 --frames 10 --width 128 --height 96

Everything is a deterministic function of the preset, the seed and the overrides.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

from ftgspp.data.scene import Camera
from ftgspp.data.synthetic import layouts
from ftgspp.data.synthetic.content import (
    build_scene,
    color_transforms,
    exposure_gains,
    render_camera,
    robust_bounds,
)
from ftgspp.data.synthetic.formats import (
    objects_json,
    poses_bounds_row,
    trajectories_json,
    write_easyvolcap_cameras,
    write_json,
    write_video,
)
from ftgspp.data.synthetic.geometry import SceneContent
from ftgspp.data.synthetic.pool import map_in_processes
from ftgspp.data.synthetic.presets import EVENT_DEFAULTS, PRESETS, SCENE_LAYOUTS, SynthConfig, resolve_config
from ftgspp.errors import InputError


def _prepare_out(out: Path, overwrite: bool) -> None:
    if out.exists() and any(out.iterdir()):
        if overwrite and (out / "gt" / "scene.json").exists():
            shutil.rmtree(out)
        else:
            raise InputError(out, "output folder is not empty (--overwrite replaces an earlier synthetic scene)")
    out.mkdir(parents=True, exist_ok=True)


# Below this many output pixels (cameras x frames x width x height), about 2 s of rendering,
# starting worker processes costs more than it saves: the scene is rendered in this process.
PARALLEL_MIN_PIXELS = 4_000_000


def synth_workers(cfg: SynthConfig) -> int:
    """Processes that render a scene's cameras side by side: one per CPU this process may use
    (``FTGSPP_SYNTH_WORKERS`` overrides), at most one per camera, and one for a small scene
    (``PARALLEL_MIN_PIXELS``)."""
    env = os.environ.get("FTGSPP_SYNTH_WORKERS", "")
    if env.isdigit() and int(env) > 0:
        n = int(env)
    elif cfg.n_cameras * cfg.n_frames * cfg.width * cfg.height < PARALLEL_MIN_PIXELS:
        n = 1
    else:
        n = len(os.sched_getaffinity(0))
    return max(1, min(n, cfg.n_cameras))


def _write_camera(out: Path, layout: str, cfg: SynthConfig, content: SceneContent, cam: Camera, ci: int,
                  transform: tuple[np.ndarray, np.ndarray], gains: np.ndarray | None, lens: object | None,
                  transient_labels: list[int]) -> tuple[tuple[float, float], dict[int, list[int]]]:
    """Render camera ``ci`` and write its frames and ground truth; returns its depth bounds
    and each object's visible pixel count per frame. A deterministic function of its
    arguments alone (the camera's noise has its own seed), so the files do not depend on
    which process renders which camera."""
    gt = out / "gt"
    held_out = ci == 0  # cams[0] is the test camera (scene.json: test_cameras)
    r = render_camera(content, cam, cfg, transform, ci, gains=gains, keep_clean=held_out)
    if lens is not None:
        frames = render_camera(content, cam, cfg, transform, ci, rays=lens.rays, gains=gains).frames
        layouts.write_layout_frames(out, layout, cam, lens.mask(frames),
                                    lambda path, frames: write_video(path, frames, cfg.fps, cfg.codec))
    elif layout == "dynerf":
        write_video(out / f"{cam.name}.mp4", r.frames, cfg.fps, cfg.codec)
    else:
        img_dir = out / "images" / cam.name
        img_dir.mkdir(parents=True, exist_ok=True)
        for f, frame in enumerate(r.frames):
            cv2.imwrite(str(img_dir / f"{f:06d}.png"), frame[..., ::-1])
    np.save(gt / "depth" / f"{cam.name}.npy", r.depth)
    np.save(gt / "flow3d" / f"{cam.name}.npy", r.flow3d)
    np.save(gt / "objects" / f"{cam.name}.npy", r.objects)
    if r.clean is not None:  # the pinhole camera's frames before noise (lens layouts: the undistorted view)
        np.save(gt / "clean" / f"{cam.name}.npy", r.clean)
    if transient_labels:
        np.save(gt / "transient" / f"{cam.name}.npy", np.isin(r.objects, transient_labels).astype(np.uint8))
    counts = {o.label: (r.objects == o.label).sum(axis=(1, 2)).tolist() for o in content.objects}
    return robust_bounds(r.depth), counts


def generate(out: str | Path, layout: str = "dynerf", preset: str = "studio", seed: int = 0,
             overwrite: bool = False, verbose: bool = False, workers: int | None = None, **overrides) -> Path:
    """Render a synthetic scene into ``out`` (``layout`` in ``SCENE_LAYOUTS``) and return ``out``.

    ``overrides`` are ``SynthConfig`` fields (n_cameras, n_frames, width, height, color_shift,
    noise, speed, ...); a lens layout's ``LAYOUT_DEFAULTS`` come first. Ground truth goes to
    ``out/gt`` (for the undistorted cameras in the lens layouts). ``workers``: processes that
    render cameras side by side (default ``synth_workers``); the files do not depend on it.
    """
    if layout not in SCENE_LAYOUTS:
        raise InputError("--layout", f"unknown layout '{layout}' (choose from {', '.join(SCENE_LAYOUTS)})")
    cfg = resolve_config(preset, seed, **{**layouts.LAYOUT_DEFAULTS.get(layout, {}), **overrides})
    out = Path(out)
    _prepare_out(out, overwrite)
    say = print if verbose else (lambda *a, **k: None)
    start = time.perf_counter()
    content, cams = build_scene(cfg)
    lenses = layouts.make_lenses(layout, cams) if layout in layouts.LENS_LAYOUTS else []
    cams = [lens.camera for lens in lenses] or cams
    transforms = color_transforms(cfg, len(cams))
    gains = exposure_gains(cfg, len(cams))
    transient_labels = [o.label for o in content.objects if o.transient()]
    gt = out / "gt"
    for sub in ("depth", "flow3d", "objects", "clean") + (("transient",) if transient_labels else ()):
        (gt / sub).mkdir(parents=True, exist_ok=True)
    tasks = [(out, layout, cfg, content, cam, ci, transforms[ci], None if gains is None else gains[ci],
              lenses[ci] if lenses else None, transient_labels) for ci, cam in enumerate(cams)]
    bounds, pixels = [], {}
    n_workers = synth_workers(cfg) if workers is None else workers
    for cam, (near_far, counts) in zip(cams, map_in_processes(_write_camera, tasks, n_workers)):
        bounds.append(near_far)
        pixels[cam.name] = counts
        say(f"  {cam.name}: {cfg.n_frames} frames, depth {near_far[0]:.2f}..{near_far[1]:.2f}"
            f" ({time.perf_counter() - start:.1f} s)")
    order = sorted(range(len(cams)), key=lambda k: cams[k].name)  # rows follow the sorted videos
    if lenses:
        layouts.write_layout_cameras(out, layout, [lenses[k] for k in order])
    elif layout == "dynerf":
        rows = [poses_bounds_row(cams[k], *bounds[k]) for k in order]
        np.save(out / "poses_bounds.npy", np.stack(rows).astype(np.float64))
    else:
        write_easyvolcap_cameras(out, [cams[k] for k in order])
    write_json(gt / "scene.json", dict(
        preset=cfg.preset, seed=cfg.seed, layout=layout, fps=cfg.fps, n_frames=cfg.n_frames,
        params={k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()
                if k not in EVENT_DEFAULTS or v != EVENT_DEFAULTS[k]},
        world="x right, y down, z forward (into the room); cameras: OpenCV, x_cam = R X + T",
        camera_names=[c.name for c in cams], test_cameras=[cams[0].name],
        cameras=[dict(name=c.name, K=c.K.tolist(), R=c.R.tolist(), T=c.T.tolist(), width=c.width,
                      height=c.height, near=bounds[k][0], far=bounds[k][1],
                      **(dict(lens=layouts.lens_metadata(lenses[k])) if lenses else {})) for k, c in enumerate(cams)],
        files=dict(depth="depth/<cam>.npy float32 [F,H,W] camera z-depth at pixel centres",
                   flow3d="flow3d/<cam>.npy float16 [F,H,W,3] world velocity of the visible point, units/s",
                   objects="objects/<cam>.npy uint8 [F,H,W] 0 = background, k = label of object k",
                   clean="clean/<cam>.npy uint8 [F,H,W,3] RGB of the test camera before sensor noise and video"
                         " coding (colour shift and exposure drift applied)",
                   **(dict(transient="transient/<cam>.npy uint8 [F,H,W] 1 where an object that exists for"
                                     " part of the clip is visible") if transient_labels else {})),
    ))
    write_json(gt / "objects.json", objects_json(content, cfg, pixels))
    write_json(gt / "trajectories.json", trajectories_json(content, cfg))
    if gains is None:
        write_json(gt / "color_transforms.json", dict(
            convention="observed = clip(I @ (I3 + dM) + b + noise); I is an RGB row vector in [0, 1]",
            noise_sigma=cfg.noise,
            cameras={c.name: dict(dM=t[0].tolist(), b=t[1].tolist()) for c, t in zip(cams, transforms)},
        ))
    else:
        write_json(gt / "color_transforms.json", dict(
            convention="observed = clip((I * gain[frame]) @ (I3 + dM) + b + noise); I is an RGB row vector in [0, 1]",
            noise_sigma=cfg.noise, exposure_drift=cfg.exposure_drift,
            cameras={c.name: dict(dM=t[0].tolist(), b=t[1].tolist(), gain=gains[k].tolist())
                     for k, (c, t) in enumerate(zip(cams, transforms))},
        ))
    say(f"wrote {layout} scene '{cfg.preset}' ({len(cams)} cameras x {cfg.n_frames} frames, "
        f"{cfg.width}x{cfg.height}) to {out} in {time.perf_counter() - start:.1f} s")
    return out


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="ftgspp synth", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output folder (must be empty or absent)")
    p.add_argument("--layout", default="dynerf", help="dynerf (camNN.mp4 + poses_bounds.npy), easyvolcap, "
                   "immersive (fisheye videos + models.json) or enerf_outdoor (easyvolcap with distortion)")
    p.add_argument("--preset", default="studio", help=f"one of {', '.join(PRESETS)}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cameras", type=int, dest="n_cameras")
    p.add_argument("--frames", type=int, dest="n_frames")
    p.add_argument("--width", type=int)
    p.add_argument("--height", type=int)
    p.add_argument("--hfov", type=float, dest="hfov_deg", help="horizontal field of view of the (undistorted) "
                   "cameras in degrees (default 55; immersive: 152)")
    p.add_argument("--color-shift", type=float, dest="color_shift", help="colour-shift strength (1 = default)")
    p.add_argument("--noise", type=float, help="sensor noise sigma (default 0.01)")
    p.add_argument("--speed", type=float, help="motion speed multiplier (default 1)")
    p.add_argument("--codec", help="DyNeRF video codec: ffv1 (lossless, default) or mp4v (lossy)")
    p.add_argument("--fps", type=float, help="frames per second (default 30; clip length = frames / fps)")
    p.add_argument("--transients", type=int, help="0-2 still objects that exist for part of the clip")
    p.add_argument("--flame", type=float, help="flicker strength of a flame-like ball (0 = none)")
    p.add_argument("--exposure-drift", type=float, dest="exposure_drift",
                   help="auto-exposure drift strength (1 = log-gain ±0.15, white balance ±0.05)")
    p.add_argument("--detail", type=float, help="texture detail in [0, 1] (1 = default; 0 = smooth gradients only)")
    p.add_argument("--overwrite", action="store_true", help="replace an earlier synthetic scene in --out")
    return p


def main(argv: list[str] | None = None) -> int:
    """``ftgspp synth`` entry point; returns the exit status."""
    args = _parser().parse_args(argv)
    knobs = ("n_cameras", "n_frames", "width", "height", "hfov_deg", "color_shift", "noise", "speed", "codec", "fps",
             "transients", "flame", "exposure_drift", "detail")
    overrides = {k: getattr(args, k) for k in knobs if getattr(args, k) is not None}
    try:
        generate(args.out, layout=args.layout, preset=args.preset, seed=args.seed,
                 overwrite=args.overwrite, verbose=True, **overrides)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0
