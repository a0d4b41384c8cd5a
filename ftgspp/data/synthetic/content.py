"""What a synthetic scene shows and how one camera records it (``ftgspp synth``).

``build_scene`` lays out the room, props, moving balls and camera rig of a ``SynthConfig``;
``render_camera`` ray-casts every frame of one camera and applies its colour shift, exposure
drift and sensor noise (``color_transforms``, ``exposure_gains``); on request it also keeps the
frames as they are just before the noise (``CameraRender.clean``: the held-out camera's
noise-free reference, ``gt/clean/``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import cv2
import numpy as np

from ftgspp.data.scene import Camera
from ftgspp.data.synthetic.geometry import ArcPath, Box, LinearPath, MovingSphere, Quad, SceneContent
from ftgspp.data.synthetic.presets import SynthConfig
from ftgspp.data.synthetic.raycast import cast_objects, cast_static
from ftgspp.data.synthetic.rig import make_rig, pixel_rays
from ftgspp.data.synthetic.textures import Texture, make_texture

_LINEAR_MID = np.array([-0.55, 0.45, 0.8])  # ball_linear position at mid-clip
_ORBIT_CENTRE = np.array([0.75, -0.35, 2.2])
_ORBIT_E2 = np.array([0.0, -0.35, 1.0]) / np.linalg.norm([0.0, -0.35, 1.0])  # arc plane tilts upwards


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
    clean: np.ndarray | None = None  # [F, H, W, 3] uint8 RGB before the sensor noise (``keep_clean``)


def render_camera(content: SceneContent, cam: Camera, cfg: SynthConfig, transform: tuple[np.ndarray, np.ndarray],
                  cam_index: int, rays: Callable[[int], np.ndarray] | None = None,
                  gains: np.ndarray | None = None, keep_clean: bool = False) -> CameraRender:
    """Ray-cast all frames of one camera, then apply its colour shift and noise.

    ``gains [F, 3]``: the camera's exposure drift per frame (``exposure_gains``), applied first.
    ``keep_clean``: also return the frames just before the noise, rounded to uint8 as the
    recorded ones are (``clean``; the noise draws, hence ``frames``, are the same either way).

    ``rays(s)`` is the camera's world ray grid ``[H*s, W*s, 3]`` (unit camera-z) through a
    lens (``layouts.Lens.rays``); default: the pinhole ``pixel_rays``.
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
                       np.empty((F, H, W, 3), np.float16), np.empty((F, H, W), np.uint8),
                       np.empty((F, H, W, 3), np.uint8) if keep_clean else None)
    for f in range(F):
        t = f / cfg.fps
        rgb = cast_objects(content, cam, sub_dirs, s, t, sub_bg, box_from_rays=lens).rgb
        img = cv2.resize(rgb.astype(np.float32), (W, H), interpolation=cv2.INTER_AREA)  # s x s box average
        if gains is not None:
            img = img * gains[f].astype(np.float32)
        img = img @ M + transform[1]
        if out.clean is not None:
            out.clean[f] = np.round(np.clip(img, 0.0, 1.0) * 255).astype(np.uint8)
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
