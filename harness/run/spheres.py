"""A second, independent scene writer: ray-cast spheres in the DyNeRF layout, with true depth.

The dense initialiser (``init.matcher=dense``, ftgspp/init/dense.py) was tuned on the scenes of
``ftgspp.data.synthetic``; to know how it does elsewhere, this writer makes scenes of another
kind, with none of that generator's code: spheres (some still, some moving in straight lines)
inside a large backdrop sphere, shaded Lambertian under one directional light, optionally
textured by a solid sine pattern, seen by an arc of cameras (a selectable count, spacing,
resolution, and optionally one camera missing from the rig) whose images carry per-camera colour
gains and offsets. Every ray is intersected with every sphere in closed form.

Written into ``out``: ``camNN.mp4`` (lossless FFV1) and ``poses_bounds.npy`` (DyNeRF/LLFF rows,
docs/design.md §5; ``cam00``, the middle slot, is the held-out camera), and ground truth in the
files ``ftgspp.diagnostics.motion.load_ground_truth`` reads: ``gt/depth/<cam>.npy`` (float32
``[F, H, W]`` camera z-depth at pixel centres), ``gt/flow3d/<cam>.npy`` (float32 ``[F, H, W, 3]``
world velocity of the visible surface), ``gt/objects/<cam>.npy`` (uint8 ``[F, H, W]``: 1 + the
index of the moving sphere seen there, 0 on still content); ``spheres.json`` has the spheres,
the cameras and the colour transforms. A study scene names it as a synthetic preset
(``synth: {preset: spheres, ...}``; arguments and checks: ``harness.spec.sphere_scene``).

    python -m harness.run.spheres --out /tmp/spheres --seed 1 --set n_cameras=6 --set missing=2
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ftgspp.errors import InputError
from harness.spec.sphere_scene import PRESET, SphereSceneConfig, resolve  # noqa: F401

LIGHT = np.array([-0.4, -0.8, -0.45]) / np.linalg.norm([-0.4, -0.8, -0.45])  # towards the light (y is down)
AMBIENT = 0.25
BACKDROP = 3.0  # backdrop sphere radius, in rig radii
BACKDROP_ALBEDO = (0.55, 0.5, 0.45)


# --------------------------------------------------------------------------- rig


def rig(cfg: SphereSceneConfig) -> list[dict[str, Any]]:
    """The written cameras: ``name``, ``K [3, 3]``, world-to-camera ``R [3, 3]``, ``T [3]``,
    ``center [3]``, in rig order (left to right), the missing slot left out. The target is
    the world origin; world y points down, as a camera's."""
    n, mid = cfg.n_cameras, cfg.n_cameras // 2
    names, k = [], 1
    for slot in range(n):
        if slot == mid:
            names.append("cam00")
        else:
            names.append(f"cam{k:02d}")
            k += 1
    f = 0.5 * cfg.width / np.tan(np.radians(cfg.hfov_deg) / 2)
    K = np.array([[f, 0, cfg.width / 2], [0, f, cfg.height / 2], [0, 0, 1.0]])
    el = np.radians(cfg.elevation_deg)
    cams = []
    for slot, name in enumerate(names):
        if cfg.missing is not None and name == f"cam{cfg.missing:02d}":
            continue
        az = np.radians((slot - (n - 1) / 2) * cfg.spacing_deg)
        center = cfg.radius * np.array([np.sin(az) * np.cos(el), -np.sin(el), -np.cos(az) * np.cos(el)])
        z = -center / np.linalg.norm(center)  # looks at the origin
        x = np.cross([0.0, 1.0, 0.0], z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        cams.append(dict(name=name, K=K, R=R, T=-R @ center, center=center))
    return cams


def spheres(cfg: SphereSceneConfig) -> dict[str, np.ndarray]:
    """Centres at t = 0 ``[S, 3]``, velocities ``[S, 3]`` (units/s), radii ``[S]``, albedos ``[S, 3]``
    and ``moving [S]`` (bool); the first ``n_moving`` move. Still spheres do not overlap."""
    rng = np.random.default_rng(cfg.seed)
    half_w = cfg.radius * np.tan(np.radians(cfg.hfov_deg) / 2)  # half the view's width at the target
    box = np.array([0.55 * half_w, 0.55 * half_w * cfg.height / cfg.width, 0.45 * half_w])
    duration = cfg.n_frames / cfg.fps
    count = cfg.n_moving + cfg.n_still
    centres, radii, vel = np.zeros((count, 3)), np.zeros(count), np.zeros((count, 3))
    for i in range(count):
        for _ in range(200):
            r = rng.uniform(0.12, 0.24) * half_w
            c = rng.uniform(-1, 1, size=3) * box
            if i < cfg.n_moving:
                d = rng.normal(size=3) * np.array([1.0, 0.3, 0.6])
                v = cfg.speed * d / np.linalg.norm(d)
                c = c - v * duration / 2  # the clip's middle inside the box
            else:
                v = np.zeros(3)
            others = range(cfg.n_moving, i)  # still spheres keep apart
            if i < cfg.n_moving or all(np.linalg.norm(c - centres[j]) > r + radii[j] + 0.05 for j in others):
                break
        centres[i], radii[i], vel[i] = c, r, v
    albedo = rng.uniform(0.25, 0.9, size=(count, 3))
    return dict(centres=centres, velocities=vel, radii=radii, albedos=albedo, moving=np.arange(count) < cfg.n_moving)


def colour_transforms(cfg: SphereSceneConfig, names: list[str]) -> dict[str, dict[str, list[float]]]:
    """Per camera: ``gain [3]`` and ``offset [3]``, the image written being ``gain * x + offset``."""
    rng = np.random.default_rng([cfg.seed, 1])
    out = {}
    for name in names:
        gain = 1 + rng.uniform(-cfg.color_gain, cfg.color_gain, 3)
        offset = rng.uniform(-cfg.color_offset, cfg.color_offset, 3)
        out[name] = dict(gain=gain.tolist(), offset=offset.tolist())
    return out


# --------------------------------------------------------------------------- ray casting


def _pattern(local: np.ndarray, freq: float) -> np.ndarray:
    """The solid texture in ``[-1, 1]`` at sphere-local points (in radii). [..., 3] -> [...]"""
    return np.sin(freq * local[..., 0]) * np.sin(freq * local[..., 1] + 1.0) * np.sin(freq * local[..., 2] + 2.0)


def cast(cfg: SphereSceneConfig, cam: dict[str, Any], s: dict[str, np.ndarray], t: float, offsets: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays through pixel centres shifted by ``offsets [2]``: z-depth ``[H, W]``, linear RGB
    ``[H, W, 3]`` and the index of the sphere hit ``[H, W]`` (-1: the backdrop)."""
    h, w = cfg.height, cfg.width
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    K = cam["K"]
    d_cam = np.stack([(u + offsets[0] - K[0, 2]) / K[0, 0], (v + offsets[1] - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    d = d_cam @ cam["R"]  # [H, W, 3] world directions, z-component 1 in the camera: t is the z-depth
    o = cam["center"]
    a = np.sum(d * d, axis=-1)
    # the backdrop: the camera is inside it, the far root
    big = BACKDROP * cfg.radius
    b, c = d @ o, o @ o - big**2
    depth = (-b + np.sqrt(b * b - a * c)) / a
    hit = np.full((h, w), -1, dtype=np.int64)
    centres = s["centres"] + s["velocities"] * t
    for i, (ci, ri) in enumerate(zip(centres, s["radii"])):
        oc = o - ci
        b, c = d @ oc, oc @ oc - ri**2
        disc = b * b - a * c
        with np.errstate(invalid="ignore"):
            ti = (-b - np.sqrt(disc)) / a
        closer = (disc >= 0) & (ti > 0) & (ti < depth)
        depth = np.where(closer, ti, depth)
        hit[closer] = i
    X = o + d * depth[..., None]  # [H, W, 3] the surface seen
    centre = np.where(hit[..., None] >= 0, centres[np.maximum(hit, 0)], 0.0)
    rad = np.where(hit >= 0, s["radii"][np.maximum(hit, 0)], big)
    normal = (X - centre) / rad[..., None]
    normal = np.where(hit[..., None] >= 0, normal, -normal)  # the backdrop is seen from inside
    albedo = np.where(hit[..., None] >= 0, s["albedos"][np.maximum(hit, 0)], np.asarray(BACKDROP_ALBEDO))
    if cfg.texture > 0:
        albedo = albedo * (1 + cfg.texture * _pattern((X - centre) / rad[..., None], cfg.texture_freq))[..., None]
    shade = AMBIENT + (1 - AMBIENT) * np.clip(normal @ LIGHT, 0, None)
    return depth, albedo * shade[..., None], hit


def render_camera(cfg: SphereSceneConfig, cam: dict[str, Any], s: dict[str, np.ndarray], times: np.ndarray,
                  transform: dict[str, list[float]], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """uint8 ``frames [F, H, W, 3]`` and ground-truth ``depth``, ``flow3d``, ``objects`` of one camera."""
    n = cfg.supersample
    subs = [np.array([(i + 0.5) / n - 0.5, (j + 0.5) / n - 0.5]) for j in range(n) for i in range(n)]
    frames, depths, flows, objects = [], [], [], []
    gain, offset = np.asarray(transform["gain"]), np.asarray(transform["offset"])
    for t in times:
        depth, _, hit = cast(cfg, cam, s, float(t), np.zeros(2))
        rgb = np.mean([cast(cfg, cam, s, float(t), off)[1] for off in subs], axis=0)
        img = np.clip(rgb, 0, 1) * gain + offset
        if cfg.noise > 0:
            img = img + rng.normal(0, cfg.noise, size=img.shape)
        frames.append((np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8))
        depths.append(depth.astype(np.float32))
        moving = (hit >= 0) & s["moving"][np.maximum(hit, 0)]
        flows.append(np.where(moving[..., None], s["velocities"][np.maximum(hit, 0)], 0.0).astype(np.float32))
        objects.append(np.where(moving, hit + 1, 0).astype(np.uint8))
    return dict(frames=np.stack(frames), depth=np.stack(depths), flow3d=np.stack(flows), objects=np.stack(objects))


def poses_bounds_row(cam: dict[str, Any], width: int, height: int, near: float, far: float) -> np.ndarray:
    """``[17]``: the 3x5 matrix [down, right, back, centre, (H, W, focal)] row-major, near, far."""
    c2w = cam["R"].T  # columns: camera x (right), y (down), z (forward) in the world
    m = np.stack([c2w[:, 1], c2w[:, 0], -c2w[:, 2], cam["center"], [height, width, cam["K"][0, 0]]], axis=1)
    return np.concatenate([m.reshape(-1), [near, far]])


def generate(out: str | Path, layout: str = "dynerf", preset: str = PRESET, seed: int = 0, **args: Any) -> Path:
    """Write the scene into ``out`` (the signature of ``ftgspp.data.synthetic.build.generate``)."""
    from ftgspp.data.synthetic.formats import write_video  # an FFV1 encoder; nothing of its scenes

    cfg = resolve({**args, "layout": layout, "seed": seed, "preset": preset})
    out = Path(out)
    for sub in ("depth", "flow3d", "objects"):
        (out / "gt" / sub).mkdir(parents=True, exist_ok=True)
    cams = rig(cfg)
    s = spheres(cfg)
    times = np.arange(cfg.n_frames) / cfg.fps
    transforms = colour_transforms(cfg, [c["name"] for c in cams])
    rows = {}
    for cam in cams:
        r = render_camera(cfg, cam, s, times, transforms[cam["name"]], np.random.default_rng([cfg.seed, 2, len(rows)]))
        write_video(out / f"{cam['name']}.mp4", r["frames"], cfg.fps, "ffv1")
        for sub in ("depth", "flow3d", "objects"):
            np.save(out / "gt" / sub / f"{cam['name']}.npy", r[sub])
        near = 0.9 * float(r["depth"].min())
        rows[cam["name"]] = poses_bounds_row(cam, cfg.width, cfg.height, near, 1.02 * float(r["depth"].max()))
    np.save(out / "poses_bounds.npy", np.stack([rows[n] for n in sorted(rows)]))
    (out / "spheres.json").write_text(json.dumps({
        "params": asdict(cfg),
        "spheres": {k: np.asarray(v).tolist() for k, v in s.items()},
        "position": "centre at time t = centres + velocities * t, t = frame / fps",
        "backdrop_radius": BACKDROP * cfg.radius,
        "cameras": {c["name"]: dict(K=c["K"].tolist(), R=c["R"].tolist(), T=c["T"].tolist()) for c in cams},
        "colour_transforms": transforms,
        "test_cameras": ["cam00"],
    }, indent=1))
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m harness.run.spheres --out DIR [--seed N] [--set missing=2 ...]``: write the scene; exit status 2 on bad
    input (``harness.run.writer_cli``)."""
    from harness.run import writer_cli

    return writer_cli.main("python -m harness.run.spheres", __doc__.split("\n\n")[0], generate, "missing=2", argv)


if __name__ == "__main__":
    raise SystemExit(main())
