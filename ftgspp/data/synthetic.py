"""``ftgspp synth``: procedural multi-view dynamic scenes with ground truth.

Renders a textured room (floor, ceiling, side walls, a back wall with a window onto a
far backdrop, two static props) and two moving textured spheres -- one on a straight
line, one on a circular arc while spinning -- seen by an arc of pinhole cameras
(``cam00`` in the middle is the test view). Each camera gets its own affine colour
shift and sensor noise, like a real rig. Output is written in the DyNeRF or the
EasyVolcap layout, or through a lens in the Immersive (fisheye) or ENeRF-Outdoor (distorted
EasyVolcap) layout (``synthetic_layouts``), plus ground truth in ``<out>/gt/`` (depth, scene
flow, object masks, trajectories, colour transforms) so that motion can be scored.

Run::

    ftgspp synth --out data/synth_studio                       # DyNeRF layout
    ftgspp synth --out data/synth_fast --layout easyvolcap --preset fast_motion
    python -m ftgspp.data.synthetic --out /tmp/s --cameras 6 --frames 10 --width 128 --height 96

Everything is a deterministic function of the preset, the seed and the overrides.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from ftgspp.data import synthetic_layouts as layouts
from ftgspp.data.scene import Camera
from ftgspp.data.synthetic_geometry import ArcPath, Box, LinearPath, MovingSphere, Quad, SceneContent
from ftgspp.data.synthetic_pool import map_in_processes
from ftgspp.data.synthetic_raycast import cast_objects, cast_static
from ftgspp.data.synthetic_rig import make_rig, pixel_rays
from ftgspp.data.synthetic_textures import Texture, make_texture
from ftgspp.errors import InputError

SCENE_LAYOUTS = ("dynerf", "easyvolcap", *layouts.LENS_LAYOUTS)
# Video codecs for the DyNeRF layout (all in .mp4 containers that OpenCV's bundled FFmpeg
# reads back). mp4v (MPEG-4 part 2, yuv420p at OpenCV's fixed ~1 bit/pixel) loses ~7 dB on
# these textures (decoded-vs-source PSNR ~33 dB), so the default is lossless FFV1.
CODECS = {"ffv1": "FFV1", "mp4v": "mp4v"}


@dataclass(frozen=True)
class SynthConfig:
    """All knobs of a synthetic scene. Presets set the motion fields; overrides win."""

    preset: str = "studio"
    seed: int = 0
    n_cameras: int = 10
    n_frames: int = 30
    fps: float = 30.0
    width: int = 256
    height: int = 192
    hfov_deg: float = 55.0
    arc_deg: float = 50.0  # total angle spanned by the camera arc
    rig_radius: float = 4.4  # camera distance to the look-at point
    supersample: int = 2  # s x s rays per pixel for the RGB images (ground truth uses pixel centres)
    codec: str = "ffv1"  # DyNeRF videos: ffv1 (lossless) | mp4v (lossy, like real footage)
    color_shift: float = 1.0  # 1 = gains +-5 %, cross terms +-1.5 %, offsets +-0.02
    noise: float = 0.01  # Gaussian sensor noise sigma (image in [0, 1])
    speed: float = 1.0  # multiplies every velocity (linear, orbit and spin)
    linear_velocity: tuple[float, float, float] = (0.45, 0.0, 0.12)  # units/s
    orbit_radius: float = 0.5
    orbit_omega: float = 1.4  # rad/s
    spin: float = 2.0  # rad/s, spin of the curved ball about the vertical
    # the events of real captures (docs/datasets.md "Synthetic presets"); off by default
    transients: int = 0  # 0-2 still objects that appear and disappear mid-clip
    occluder_pass: bool = False  # a ball that passes behind the crate
    flame: float = 0.0  # flicker strength of a flame-like ball whose colours change every frame
    exposure_drift: float = 0.0  # 1: auto-exposure log-gain drifts by up to ±0.15, white balance ±0.05
    window: bool = True  # False: the back wall has no window onto the far backdrop
    detail: float = 1.0  # texture detail (checker, noise, waves, marks); 0 = smooth colour gradients only


# fields whose default leaves the scene as it was before they existed: left out of scene.json
# at their default, so earlier scenes stay byte-identical
EVENT_DEFAULTS = dict(transients=0, occluder_pass=False, flame=0.0, exposure_drift=0.0, window=True,
                      detail=1.0)


PRESETS: dict[str, dict] = {
    # slow, localized motion as in DyNeRF: the balls move ~0.5 units over one second
    "studio": {},
    # SelfCap-like: ~4x faster and larger motion
    "fast_motion": dict(linear_velocity=(1.8, -0.15, 0.35), orbit_radius=0.75, orbit_omega=4.0, spin=5.0),
    # nothing moves
    "static": dict(linear_velocity=(0.0, 0.0, 0.0), orbit_omega=0.0, spin=0.0),
    # secret 1: two still objects that each exist for ~40 % of a 2-s clip (transient content)
    "transient": dict(transients=2, n_frames=60),
    # a ball that passes behind the crate: objects.json has its visible pixels per frame
    "occlusion": dict(occluder_pass=True),
    # secret 5: DyNeRF-like per-camera exposure and white balance drifting over time
    "exposure_drift": dict(exposure_drift=1.0),
    # secret 3, the DyNeRF ladder: 4 s (120 frames) of slow motion
    "long_slow": dict(n_frames=120, speed=0.4),
    # secret 3, the SelfCap ladder: 1 s of fast motion (fast_motion, 1.25x faster)
    "short_fast": dict(linear_velocity=(1.8, -0.15, 0.35), orbit_radius=0.75, orbit_omega=4.0, spin=5.0, speed=1.25),
    # secret 3's depth prior control: the studio with its window closed (no far backdrop)
    "closed_window": dict(window=False),
    # a flame-like ball: geometry fixed, colours redrawn every frame (DyNeRF's flames and steam)
    "flame": dict(flame=0.6),
    # "model no more than a scene needs": nothing moves, the textures are smooth colour gradients only
    "plain": dict(linear_velocity=(0.0, 0.0, 0.0), orbit_omega=0.0, spin=0.0, detail=0.0),
}

_LINEAR_MID = np.array([-0.55, 0.45, 0.8])  # ball_linear position at mid-clip
_ORBIT_CENTRE = np.array([0.75, -0.35, 2.2])
_ORBIT_E2 = np.array([0.0, -0.35, 1.0]) / np.linalg.norm([0.0, -0.35, 1.0])  # arc plane tilts upwards


def resolve_config(preset: str = "studio", seed: int = 0, **overrides) -> SynthConfig:
    """Preset values, then ``overrides`` (any ``SynthConfig`` field), validated."""
    if preset not in PRESETS:
        raise InputError("--preset", f"unknown preset '{preset}' (choose from {', '.join(sorted(PRESETS))})")
    names = {f.name for f in fields(SynthConfig)} - {"preset", "seed"}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise InputError("synth", f"unknown option(s) {', '.join(unknown)} (choose from {', '.join(sorted(names))})")
    cfg = replace(SynthConfig(preset=preset, seed=seed), **{**PRESETS[preset], **overrides})
    cfg = replace(cfg, linear_velocity=tuple(float(x) for x in cfg.linear_velocity))
    checks = [
        ("--cameras", 2 <= cfg.n_cameras <= 100, "needs 2..100 cameras"),
        ("--frames", cfg.n_frames >= 1, "needs at least 1 frame"),
        ("--width", cfg.width >= 16 and cfg.width % 2 == 0, "width must be even and >= 16"),
        ("--height", cfg.height >= 16 and cfg.height % 2 == 0, "height must be even and >= 16"),
        ("--color-shift", cfg.color_shift >= 0, "must be >= 0"),
        ("--noise", cfg.noise >= 0, "must be >= 0"),
        ("--speed", cfg.speed >= 0, "must be >= 0"),
        ("fps", cfg.fps > 0, "must be > 0"),
        ("supersample", cfg.supersample >= 1, "must be >= 1"),
        ("--codec", cfg.codec in CODECS, f"unknown codec '{cfg.codec}' (choose from {', '.join(CODECS)})"),
        ("--transients", cfg.transients in (0, 1, 2), "must be 0, 1 or 2"),
        ("--flame", cfg.flame >= 0, "must be >= 0"),
        ("--exposure-drift", cfg.exposure_drift >= 0, "must be >= 0"),
        ("--detail", 0 <= cfg.detail <= 1, "must be in [0, 1]"),
    ]
    for where, ok, problem in checks:
        if not ok:
            raise InputError(where, problem)
    return cfg


# ----------------------------------------------------------------------------- the scene


def build_scene(cfg: SynthConfig) -> tuple[SceneContent, list[Camera]]:
    """The room, props, moving balls and camera rig of ``cfg`` (textures drawn from the seed)."""
    rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 0]))
    ex, ey, ez = np.eye(3)

    def tex(hue: float, scale: float, salt: int, period_u: float | None = None, vivid: bool = False) -> Texture:
        return _texture(rng, cfg, hue, scale, salt, period_u, vivid=vivid)

    inf = np.inf
    static = [  # room planes end at the back wall (z = 5); the window looks onto the backdrop
        Quad("floor", np.array([0.0, 1.0, 0.0]), ex, ez, -ey, tex(30, 0.8, 1), (-inf, inf, -inf, 5.0)),
        Quad("ceiling", np.array([0.0, -2.4, 0.0]), ex, ez, ey, tex(60, 1.2, 2), (-inf, inf, -inf, 5.0)),
        Quad("back_wall", np.array([0.0, 0.0, 5.0]), ex, ey, -ez, tex(200, 1.0, 3),
             holes=((-1.7, 0.9, -1.4, 0.3),) if cfg.window else ()),
        Quad("left_wall", np.array([-3.0, 0.0, 0.0]), ez, ey, ex, tex(100, 1.0, 4), (-inf, 5.0, -inf, inf)),
        Quad("right_wall", np.array([3.0, 0.0, 0.0]), ez, ey, -ex, tex(330, 1.0, 5), (-inf, 5.0, -inf, inf)),
        Quad("backdrop", np.array([0.0, 0.0, 26.0]), ex, ey, -ez, tex(140, 3.5, 6)),
        Box("crate", np.array([1.1, 0.25, 2.6]), np.array([1.9, 1.0, 3.4]), tex(15, 0.5, 7)),
        Box("pillar", np.array([-2.0, -2.4, 3.0]), np.array([-1.6, 1.0, 3.4]), tex(270, 0.6, 8)),
    ]
    if not cfg.window:  # closed: no backdrop (its texture is still drawn, so the rest stays the same)
        static = [q for q in static if q.name != "backdrop"]

    t_mid = (cfg.n_frames - 1) / (2 * cfg.fps)
    v_lin = np.array(cfg.linear_velocity) * cfg.speed
    omega = cfg.orbit_omega * cfg.speed
    r_lin, r_arc = 0.42, 0.36
    objects = [
        MovingSphere("ball_linear", 1, r_lin, LinearPath(_LINEAR_MID, v_lin, t_mid),
                     tex(0, 0.35, 9, 2 * np.pi * r_lin, vivid=True)),
        MovingSphere("ball_curved", 2, r_arc,
                     ArcPath(_ORBIT_CENTRE, cfg.orbit_radius, omega, -np.pi / 2 - omega * t_mid, ex, _ORBIT_E2),
                     tex(50, 0.3, 10, 2 * np.pi * r_arc, vivid=True), spin=cfg.spin * cfg.speed),
    ]
    objects += _event_objects(cfg, rng, t_mid)
    cams = make_rig(cfg.n_cameras, cfg.width, cfg.height, cfg.hfov_deg, cfg.arc_deg, cfg.rig_radius,
                    target=np.array([0.0, 0.2, 1.4]), eye_height=-0.3)
    return SceneContent(static, objects), cams


def _texture(rng: np.random.Generator, cfg: SynthConfig, hue: float, scale: float, salt: int,
             period_u: float | None = None, vivid: bool = False) -> Texture:
    """``make_texture`` at ``cfg.detail`` (the random draws do not depend on it)."""
    return replace(make_texture(rng, hue, scale, salt, period_u, vivid), detail=cfg.detail)


def _event_objects(cfg: SynthConfig, rng: np.random.Generator, t_mid: float) -> list[MovingSphere]:
    """The optional objects of ``cfg`` (transients, the occluded ball, the flame), drawn after the
    default scene's so that its textures do not change."""
    duration = cfg.n_frames / cfg.fps
    still = np.zeros(3)
    out = []
    # (centre on the floor, radius, the fraction of the clip it exists in)
    spots = [(np.array([-1.55, 0.62, 1.9]), 0.38, (0.2, 0.6)), (np.array([0.35, 0.7, 3.7]), 0.3, (0.45, 0.85))]
    for k, (centre, r, (a, b)) in enumerate(spots[: cfg.transients]):
        out.append(MovingSphere(f"transient_{k}", 3 + k, r, LinearPath(centre, still, t_mid),
                                _texture(rng, cfg, 200 + 80 * k, 0.3, 11 + k, 2 * np.pi * r, vivid=True),
                                visible=(a * duration, b * duration), role="transient"))
    if cfg.occluder_pass:  # crosses x = 0.2 .. 2.8 at z = 4.1, behind the crate (x 1.1 .. 1.9, z 2.6 .. 3.4)
        r = 0.28
        v = np.array([2.6 * cfg.speed / max((cfg.n_frames - 1) / cfg.fps, 1e-6), 0.0, 0.0])  # one crossing
        out.append(MovingSphere("ball_occluded", 5, r, LinearPath(np.array([1.5, 0.62, 4.1]), v, t_mid, 1.3),
                                _texture(rng, cfg, 160, 0.3, 13, 2 * np.pi * r, vivid=True)))
    if cfg.flame > 0:
        r = 0.4
        out.append(MovingSphere("flame", 6, r, LinearPath(np.array([-0.9, 0.55, 3.9]), still, t_mid),
                                _texture(rng, cfg, 20, 0.3, 14, 2 * np.pi * r, vivid=True), flicker=cfg.flame,
                                role="flame"))
    return out


def exposure_gains(cfg: SynthConfig, n_cameras: int) -> np.ndarray | None:
    """Per-camera, per-frame RGB gains ``[C, F, 3]`` of the auto-exposure drift, or None.

    A DyNeRF-like model: each camera's exposure (a common log-gain) and white balance (a
    log-gain per channel) wander smoothly over time, as sums of three slow sinusoids
    (0.1–0.6 Hz, random phases) scaled to ±0.15 and ±0.05 × ``exposure_drift``.
    """
    if cfg.exposure_drift <= 0:
        return None
    rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 3]))
    t = np.arange(cfg.n_frames) / cfg.fps

    def wander(amplitude: float, shape: tuple[int, ...]) -> np.ndarray:  # [*shape, F]
        freq = rng.uniform(0.1, 0.6, (*shape, 3, 1))
        phase = rng.uniform(0, 2 * np.pi, (*shape, 3, 1))
        return amplitude * np.sin(2 * np.pi * freq * t + phase).sum(axis=-2) / 3.0

    exposure = wander(0.15 * cfg.exposure_drift, (n_cameras,))  # [C, F]
    balance = wander(0.05 * cfg.exposure_drift, (n_cameras, 3))  # [C, 3, F]
    return np.exp(exposure[:, :, None] + np.moveaxis(balance, 1, 2))


def color_transforms(cfg: SynthConfig, n_cameras: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per-camera ``(dM [3, 3], b [3])`` with ``observed = I @ (I3 + dM) + b``."""
    rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 1]))
    out = []
    for _ in range(n_cameras):
        dM = rng.uniform(-0.015, 0.015, (3, 3))
        dM[np.diag_indices(3)] = rng.uniform(-0.05, 0.05, 3)
        b = rng.uniform(-0.02, 0.02, 3)
        out.append((dM * cfg.color_shift, b * cfg.color_shift))
    return out


@dataclass
class CameraRender:
    """Everything rendered for one camera."""

    frames: np.ndarray  # [F, H, W, 3] uint8 RGB, as the camera records it
    depth: np.ndarray  # [F, H, W] float32 camera z-depth at pixel centres
    flow3d: np.ndarray  # [F, H, W, 3] float16 world velocity (units/s) of the visible point
    objects: np.ndarray  # [F, H, W] uint8, 0 = background, k = object k


def render_camera(content: SceneContent, cam: Camera, cfg: SynthConfig, transform: tuple[np.ndarray, np.ndarray],
                  cam_index: int, rays: Callable[[int], np.ndarray] | None = None,
                  gains: np.ndarray | None = None) -> CameraRender:
    """Ray-cast all frames of one camera, then apply its colour shift and noise.

    ``gains [F, 3]``: the camera's exposure drift per frame (``exposure_gains``), applied first.

    ``rays(s)`` is the camera's world ray grid ``[H*s, W*s, 3]`` (unit camera-z) through a
    lens (``synthetic_layouts.Lens.rays``); default: the pinhole ``pixel_rays``.
    """
    H, W, s = cam.height, cam.width, cfg.supersample
    lens = rays is not None
    sub_dirs, cen_dirs = (rays(s), rays(1)) if lens else (pixel_rays(cam, s), pixel_rays(cam, 1))
    sub_bg = cast_static(content, cam.center, sub_dirs)  # RGB only
    sub_bg.label = sub_bg.flow = None
    cen_bg = cast_static(content, cam.center, cen_dirs, colour=False)  # ground truth only
    M = np.eye(3) + transform[0]
    noise_rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 2, cam_index]))
    F = cfg.n_frames
    out = CameraRender(np.empty((F, H, W, 3), np.uint8), np.empty((F, H, W), np.float32),
                       np.empty((F, H, W, 3), np.float16), np.empty((F, H, W), np.uint8))
    for f in range(F):
        t = f / cfg.fps
        rgb = cast_objects(content, cam, sub_dirs, s, t, sub_bg, box_from_rays=lens).rgb
        img = cv2.resize(rgb.astype(np.float32), (W, H), interpolation=cv2.INTER_AREA)  # s x s box average
        if gains is not None:
            img = img * gains[f].astype(np.float32)
        img = img @ M + transform[1]
        if cfg.noise > 0:
            img = img + noise_rng.normal(0.0, cfg.noise, img.shape)
        out.frames[f] = np.round(np.clip(img, 0.0, 1.0) * 255).astype(np.uint8)
        gt = cast_objects(content, cam, cen_dirs, 1, t, cen_bg, box_from_rays=lens)
        out.depth[f] = gt.depth
        out.flow3d[f] = gt.flow
        out.objects[f] = gt.label
    return out


def robust_bounds(depth: np.ndarray) -> tuple[float, float]:
    """Near / far of a depth stack: its 0.1 and 99.9 percentiles."""
    near, far = np.percentile(depth, [0.1, 99.9])
    return float(near), float(far)


# ----------------------------------------------------------------------------- writers


def write_video(path: Path, frames: np.ndarray, fps: float, codec: str = "ffv1") -> None:
    """Encode uint8 RGB frames ``[F, H, W, 3]`` as an mp4 with OpenCV (``codec`` in ``CODECS``)."""
    F, H, W, _ = frames.shape
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*CODECS[codec]), fps, (W, H))
    if not writer.isOpened():
        raise RuntimeError(f"{path}: OpenCV cannot open a '{codec}' video writer")
    for frame in frames:
        writer.write(np.ascontiguousarray(frame[..., ::-1]))
    writer.release()


def poses_bounds_row(cam: Camera, near: float, far: float) -> np.ndarray:
    """One LLFF/DyNeRF ``poses_bounds`` row ``[17]``: 3x5 [down, right, back, centre, hwf], near, far."""
    c2w = cam.R.T  # OpenCV camera-to-world axes as columns: [x right, y down, z forward]
    pose = np.stack([c2w[:, 1], c2w[:, 0], -c2w[:, 2], cam.center,
                     [cam.height, cam.width, cam.K[0, 0]]], axis=1)  # [3, 5]
    return np.concatenate([pose.reshape(-1), [near, far]])


def write_easyvolcap_cameras(out: Path, cams: list[Camera]) -> None:
    """``intri.yml`` and ``extri.yml`` as OpenCV FileStorage YAML."""
    intri = cv2.FileStorage(str(out / "intri.yml"), cv2.FILE_STORAGE_WRITE)
    extri = cv2.FileStorage(str(out / "extri.yml"), cv2.FILE_STORAGE_WRITE)
    for fs in (intri, extri):
        fs.startWriteStruct("names", cv2.FileNode_SEQ)
        for cam in cams:
            fs.write("", cam.name)
        fs.endWriteStruct()
    for cam in cams:
        intri.write(f"K_{cam.name}", cam.K)
        intri.write(f"D_{cam.name}", np.zeros((1, 5)))
        intri.write(f"H_{cam.name}", int(cam.height))
        intri.write(f"W_{cam.name}", int(cam.width))
        extri.write(f"R_{cam.name}", cv2.Rodrigues(cam.R)[0])
        extri.write(f"Rot_{cam.name}", cam.R)
        extri.write(f"T_{cam.name}", cam.T.reshape(3, 1))
    intri.release()
    extri.release()


def _write_json(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(obj, indent=1) + "\n")


def _trajectories(content: SceneContent, cfg: SynthConfig) -> dict:
    times = np.arange(cfg.n_frames) / cfg.fps
    objs = []
    for o in content.objects:
        objs.append(dict(
            label=o.label, name=o.name, kind=o.path.kind, shape="sphere", radius=o.radius,
            angular_velocity=o.angular_velocity().tolist(),
            path={k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in asdict(o.path).items()},
            position=[o.path.position(t).tolist() for t in times],
            velocity=[o.path.velocity(t).tolist() for t in times],
        ))
    return dict(units="world units; velocity in units/s; angular_velocity in rad/s (world axes)",
                fps=cfg.fps, times=times.tolist(), objects=objs)


def _objects(content: SceneContent, cfg: SynthConfig, pixels: dict[str, dict[int, list[int]]]) -> dict:
    """``gt/objects.json``: every object's id, role and existence window, and its visible pixels
    per camera and frame (0 while it is absent or hidden behind something)."""
    times = np.arange(cfg.n_frames) / cfg.fps
    objs = []
    for o in content.objects:
        a, b = o.visible
        objs.append(dict(label=o.label, name=o.name, role=o.role,
                         exists=[None if not np.isfinite(a) else a, None if not np.isfinite(b) else b],
                         present=[o.present(t) for t in times],
                         visible_pixels={cam: counts[o.label] for cam, counts in pixels.items()}))
    return dict(note="exists: [appears, disappears) in seconds, null = the whole clip; visible_pixels per "
                     "camera and frame from gt/objects", fps=cfg.fps, objects=objs)


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
    r = render_camera(content, cam, cfg, transform, ci, gains=gains)
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
    for sub in ("depth", "flow3d", "objects") + (("transient",) if transient_labels else ()):
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
    _write_json(gt / "scene.json", dict(
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
                   **(dict(transient="transient/<cam>.npy uint8 [F,H,W] 1 where an object that exists for"
                                     " part of the clip is visible") if transient_labels else {})),
    ))
    _write_json(gt / "objects.json", _objects(content, cfg, pixels))
    _write_json(gt / "trajectories.json", _trajectories(content, cfg))
    if gains is None:
        _write_json(gt / "color_transforms.json", dict(
            convention="observed = clip(I @ (I3 + dM) + b + noise); I is an RGB row vector in [0, 1]",
            noise_sigma=cfg.noise,
            cameras={c.name: dict(dM=t[0].tolist(), b=t[1].tolist()) for c, t in zip(cams, transforms)},
        ))
    else:
        _write_json(gt / "color_transforms.json", dict(
            convention="observed = clip((I * gain[frame]) @ (I3 + dM) + b + noise); I is an RGB row vector in [0, 1]",
            noise_sigma=cfg.noise, exposure_drift=cfg.exposure_drift,
            cameras={c.name: dict(dM=t[0].tolist(), b=t[1].tolist(), gain=gains[k].tolist())
                     for k, (c, t) in enumerate(zip(cams, transforms))},
        ))
    say(f"wrote {layout} scene '{cfg.preset}' ({len(cams)} cameras x {cfg.n_frames} frames, "
        f"{cfg.width}x{cfg.height}) to {out} in {time.perf_counter() - start:.1f} s")
    return out


# ----------------------------------------------------------------------------- command line


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


if __name__ == "__main__":
    # through the importable module: its functions and classes then pickle by their real names
    # for the worker processes that render cameras (``synthetic_pool``), which __main__'s do not
    from ftgspp.data.synthetic import main as _main

    raise SystemExit(_main())
