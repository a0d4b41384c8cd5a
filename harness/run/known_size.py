"""A scene of known size: K Gaussians drawn by the trainer's own renderer, for the budget finder.

The smallest sufficient budget is a measured answer; to know whether the finder measures it
right, it needs a scene whose answer is known. This one is drawn from exactly ``k`` Gaussians
that FreeTimeGS can represent one for one: constant RGB colours (a DC-only spherical
harmonic), constant opacity over the whole clip, and either no motion or straight-line motion
at a constant velocity (FreeTimeGS's motion model), on the black background the trainer
composites onto (``TrainConfig.background``). Frames are rendered with ``ftgspp.render.render``
(the ``cpu`` backend training uses), seen by the synthetic scenes' camera rig
(``ftgspp.data.synthetic.rig``: ``cam00``, the middle camera, is held out) and written in the
DyNeRF layout with lossless video and no colour shift, so no budget has to spend Gaussians on
anything but the blobs. A budget of ``k`` can in principle redraw every frame exactly;
``reports/budget`` shows what the finder answers (reports/FINDINGS.md reads it).

Noise-free (``noise_sd: 0``, the default and the scene of the committed runs) the scene has no
PSNR ceiling: a model that fits it better keeps gaining, so a saturation rule need never stop
(the committed search, reports/budget/budget_known_size, kept doubling to 16,000). With
``noise_sd: σ`` every pixel and channel of every camera gets N(0, σ²) in 8-bit units before the
8-bit rounding (clipped to [0, 255]; seeded by ``(seed, NOISE_STREAM, camera index)``, apart from
the Gaussians' stream), so a perfect model's held-out PSNR is about 20·log10(255/σ) (σ = 2: ≈ 42
dB; higher where the black background clips the noise) — ``known_size.json`` records the value
measured on the held-out camera (``noise_floor_psnr``). ``study budget --preset known_size`` uses
σ = 2 (``cli.budget.NOISE_SD``).

A study scene names it as a synthetic preset (``synth: {preset: known_size, k: 500}``; its
arguments and their checks are ``harness.spec.known_scene``, and ``run.scenes`` dispatches it here); ``study budget --preset known_size`` searches it. The true
parameters are kept beside the videos in ``known_size.npz`` and described in
``known_size.json``. It lives in the harness, not in ``ftgspp.data.synthetic``: it is an
instrument for checking the harness's budget answer, and it draws with the trainer's renderer
as it is.

With ``ground_truth: true`` it also writes the held-out camera's (``cam00``) ground truth in
the files the diagnostics read (``ftgspp/diagnostics/motion.py`` ``load_ground_truth``,
``ftgspp/diagnostics/truth.py``), so that a run on it scores role switching against the truth: each true
Gaussian is one object that never hands its pixels to another, so the true Gaussians' own
score is the level of "no role switching" (``motion_role_switch_gt``). ``gt/objects/cam00.npy``
(uint16 ``[F, H, W]``) holds, per pixel, 1 + the index of the *moving* true Gaussian that
carries it (the largest compositing weight T·α there, at least ``CARRY_MIN``), 0 where a
still Gaussian or nothing carries it; ``gt/depth`` the carrier's centre depth (NaN where
nothing carries the pixel); ``gt/flow3d`` the true velocities composited like a colour (Σ T_i α_i
v_i / Σ T_i α_i, as the diagnostics composite a model's; 0 where nothing carries the pixel), the
velocity of what the pixel shows where Gaussians overlap; ``gt/clean`` the noise-free frames (the
videos themselves when ``noise_sd`` is 0); ``gt/gaussians.npz`` the true Gaussians. Only
``cam00``: the training cameras have no ground truth, so the initialisation's scores against
it (``ftgspp/init/quality.py``, which need every training camera's) stay off, as without it.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ftgspp.errors import InputError
from harness.spec.known_scene import EYE_HEIGHT, PRESET, RIG_FIELDS, TARGET, KnownSizeConfig, resolve  # noqa: F401


def draw_gaussians(cfg: KnownSizeConfig) -> dict[str, np.ndarray]:
    """The scene's ``k`` Gaussians: centres at the clip's middle, velocities, scales (activated),
    rotations (w, x, y, z), opacities and RGB colours, all numpy ``float32``."""
    rng = np.random.default_rng(cfg.seed)
    k = cfg.k
    half_w = cfg.rig.rig_radius * np.tan(np.radians(cfg.rig.hfov_deg) / 2)  # half the view's width at the target
    box = np.array([0.8 * half_w, 0.8 * half_w * cfg.rig.height / cfg.rig.width, 0.2 * cfg.rig.rig_radius])
    duration = cfg.rig.n_frames / cfg.rig.fps
    moving = np.zeros(k, dtype=bool)
    moving[rng.permutation(k)[: round(cfg.moving_share * k)]] = True
    direction = rng.normal(size=(k, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    velocity = np.where(moving[:, None], cfg.speed * direction, 0.0)
    reach = np.abs(velocity) * duration / 2  # stay inside the box over the clip
    means = TARGET + rng.uniform(-1, 1, size=(k, 3)) * np.maximum(box - reach, 0.05 * box)
    focal = 0.5 * cfg.rig.width / np.tan(np.radians(cfg.rig.hfov_deg) / 2)
    base = cfg.sigma_px * cfg.rig.rig_radius / focal  # world size of sigma_px pixels at the target's depth
    scales = base * np.exp(rng.uniform(np.log(0.6), np.log(1.6), size=(k, 3)))
    quats = rng.normal(size=(k, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    return {
        "means": means, "velocities": velocity, "scales": scales, "quats": quats,
        "opacities": rng.uniform(0.75, 0.95, size=k), "colors": rng.uniform(0.1, 0.95, size=(k, 3)),
        "moving": moving.astype(np.float32),
    }


def render_levels(g: dict[str, np.ndarray], cam: Any, times: np.ndarray, t_mid: float) -> np.ndarray:
    """RGB frames ``[F, H, W, 3]`` of the Gaussians seen by ``cam`` at ``times``, float32 in 8-bit
    units (0–255, not rounded)."""
    import torch

    from ftgspp.render import render

    t = {name: torch.as_tensor(v, dtype=torch.float32) for name, v in g.items()}
    viewmat = torch.eye(4)
    viewmat[:3, :3] = torch.as_tensor(cam.R, dtype=torch.float32)
    viewmat[:3, 3] = torch.as_tensor(cam.T, dtype=torch.float32)
    K = torch.as_tensor(cam.K, dtype=torch.float32)
    frames = []
    with torch.no_grad():
        for time in times:
            means = t["means"] + t["velocities"] * float(time - t_mid)
            out = render(means, t["quats"], t["scales"], t["opacities"], t["colors"], viewmat, K, cam.width,
                         cam.height, torch.zeros(3), backend="cpu")
            frames.append(out.image.clamp(0, 1).numpy() * 255)
    return np.stack(frames)


def render_frames(g: dict[str, np.ndarray], cam: Any, times: np.ndarray, t_mid: float) -> np.ndarray:
    """uint8 RGB frames ``[F, H, W, 3]`` of the Gaussians seen by ``cam`` at ``times`` (noise-free)."""
    return (render_levels(g, cam, times, t_mid) + 0.5).astype(np.uint8)


NOISE_STREAM = 56  # the sensor noise's random stream, apart from the Gaussians' (seed, NOISE_STREAM, camera)


def add_noise(level: np.ndarray, sd: float, rng: np.random.Generator) -> np.ndarray:
    """uint8 of ``level`` (8-bit units, any shape) plus N(0, sd²) per element, rounded to the
    nearest level and clipped to [0, 255], as a sensor's read-out."""
    return np.clip(np.rint(level + rng.normal(0.0, sd, size=level.shape)), 0, 255).astype(np.uint8)


def noise_floor_psnr(levels: np.ndarray, noisy: np.ndarray) -> float:
    """The held-out PSNR a perfect model scores on ``noisy`` frames (uint8 ``[F, H, W, 3]``): mean
    over frames of the PSNR (data range 1, as ``ftgspp.image_metrics.psnr``) of the noise-free
    render ``levels`` (``render_levels``: what the true Gaussians draw, unrounded)."""
    err = (levels.astype(np.float64) - noisy.astype(np.float64)) / 255
    mse = (err**2).reshape(len(err), -1).mean(axis=1)
    return float(np.mean(-10 * np.log10(mse)))


OPTIONAL = ("ground_truth", "noise_sd")  # arguments named in known_size.json only when set (as before them)
CARRY_MIN = 1.0 / 255  # a weight below one 8-bit level carries nothing
CARRIER_CHUNK = 128  # Gaussians rendered as one-hot colour channels per pass


def carriers(g: dict[str, np.ndarray], cam: Any, times: np.ndarray, t_mid: float
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame and pixel, the true Gaussian with the largest compositing weight T_i α_i, that
    weight, and the velocities composited with those weights: int64 ``[F, H, W]`` (−1 where no
    weight reaches ``CARRY_MIN``), float32 ``[F, H, W]`` and float32 ``[F, H, W, 3]`` (0 there).
    The weights are renders of one-hot colours with the trainer's renderer (a Gaussian's channel
    of the image is its weight), ``CARRIER_CHUNK`` channels a pass; the velocity is a render
    of the velocities as colours, over its alpha."""
    import torch

    from ftgspp.render import render

    t = {name: torch.as_tensor(v, dtype=torch.float32) for name, v in g.items()}
    k = len(g["means"])
    viewmat = torch.eye(4)
    viewmat[:3, :3] = torch.as_tensor(cam.R, dtype=torch.float32)
    viewmat[:3, 3] = torch.as_tensor(cam.T, dtype=torch.float32)
    K = torch.as_tensor(cam.K, dtype=torch.float32)
    index = np.full((len(times), cam.height, cam.width), -1, dtype=np.int64)
    weight = np.zeros((len(times), cam.height, cam.width), dtype=np.float32)
    velocity = np.zeros((len(times), cam.height, cam.width, 3), dtype=np.float32)
    with torch.no_grad():
        for f, time in enumerate(times):
            means = t["means"] + t["velocities"] * float(time - t_mid)
            out = render(means, t["quats"], t["scales"], t["opacities"], t["velocities"], viewmat, K, cam.width,
                         cam.height, torch.zeros(3), backend="cpu")
            alpha = out.alpha.numpy()  # [H, W, 1]
            velocity[f] = np.where(alpha >= CARRY_MIN, out.image.numpy() / np.maximum(alpha, CARRY_MIN), 0.0)
            for start in range(0, k, CARRIER_CHUNK):
                n = min(CARRIER_CHUNK, k - start)
                onehot = torch.zeros(k, n)
                onehot[torch.arange(start, start + n), torch.arange(n)] = 1.0
                w = render(means, t["quats"], t["scales"], t["opacities"], onehot, viewmat, K, cam.width,
                           cam.height, torch.zeros(n), backend="cpu").image.numpy()  # [H, W, n]
                best, arg = w.max(axis=-1), w.argmax(axis=-1)
                better = best > weight[f]
                weight[f][better], index[f][better] = best[better], start + arg[better]
    index[weight < CARRY_MIN] = -1
    velocity[index < 0] = 0.0
    return index, weight, velocity


def write_ground_truth(out: Path, g: dict[str, np.ndarray], cam: Any, times: np.ndarray, t_mid: float,
                       frames: np.ndarray) -> None:
    """``out/gt/``: camera ``cam``'s carrier ids, depth, scene flow and noise-free frames
    (``frames``, uint8 ``[F, H, W, 3]``), and the true Gaussians (module docstring)."""
    gt = out / "gt"
    for sub in ("objects", "depth", "flow3d", "clean"):
        (gt / sub).mkdir(parents=True, exist_ok=True)
    index, _, velocity = carriers(g, cam, times, t_mid)
    carried = index >= 0
    idx = np.where(carried, index, 0)
    moving = g["moving"][idx] > 0  # [F, H, W]
    objects = np.where(carried & moving, idx + 1, 0).astype(np.uint16)
    centres = g["means"][None] + g["velocities"][None] * (times - t_mid)[:, None, None]  # [F, k, 3]
    z = (centres @ np.asarray(cam.R).T + np.asarray(cam.T))[..., 2]  # [F, k]
    depth = np.where(carried, np.take_along_axis(z, idx.reshape(len(times), -1), axis=1).reshape(idx.shape), np.nan)
    flow = velocity
    np.save(gt / "objects" / f"{cam.name}.npy", objects)
    np.save(gt / "depth" / f"{cam.name}.npy", depth.astype(np.float32))
    np.save(gt / "flow3d" / f"{cam.name}.npy", flow.astype(np.float16))
    np.save(gt / "clean" / f"{cam.name}.npy", np.asarray(frames, dtype=np.uint8))
    np.savez(gt / "gaussians.npz", **g, t_mid=t_mid)


def generate(out: str | Path, layout: str = "dynerf", preset: str = PRESET, seed: int = 0, **args: Any) -> Path:
    """Write the scene into ``out`` (the signature of ``ftgspp.data.synthetic.build.generate``)."""
    from ftgspp.data.synthetic.formats import poses_bounds_row, write_video
    from ftgspp.data.synthetic.rig import make_rig

    cfg = resolve({**args, "layout": layout, "seed": seed})
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    g = draw_gaussians(cfg)
    rig = cfg.rig
    cams = make_rig(rig.n_cameras, rig.width, rig.height, rig.hfov_deg, rig.arc_deg, rig.rig_radius,
                    target=TARGET, eye_height=EYE_HEIGHT)
    times = np.arange(cfg.rig.n_frames) / cfg.rig.fps
    t_mid = float(times[-1]) / 2
    rows, floor = {}, None
    for i, cam in enumerate(cams):
        levels = render_levels(g, cam, times, t_mid)
        frames = clean = (levels + 0.5).astype(np.uint8)
        if cfg.noise_sd > 0:
            frames = add_noise(levels, cfg.noise_sd, np.random.default_rng([cfg.seed, NOISE_STREAM, i]))
            if i == 0:  # the held-out camera: what a perfect model scores there
                floor = noise_floor_psnr(levels, frames)
        write_video(out / f"{cam.name}.mp4", frames, cfg.rig.fps, "ffv1")
        if cfg.ground_truth and cam.name == cams[0].name:  # the held-out camera
            write_ground_truth(out, g, cam, times, t_mid, clean)
        depth = (g["means"] @ cam.R.T + cam.T)[:, 2]
        rows[cam.name] = poses_bounds_row(cam, max(0.1, float(depth.min()) - 1.0), float(depth.max()) + 1.0)
    np.save(out / "poses_bounds.npy", np.stack([rows[n] for n in sorted(rows)]).astype(np.float64))
    np.savez(out / "known_size.npz", **g, t_mid=t_mid)
    (out / "known_size.json").write_text(json.dumps({
        "k": cfg.k, "moving": int(g["moving"].sum()), "params": {**{k: v for k, v in asdict(cfg).items()
                                                                   if k != "rig" and (k not in OPTIONAL or v)},
                   **{f: getattr(cfg.rig, f) for f in RIG_FIELDS}}, "test_cameras": [cams[0].name],
        "gaussians": "known_size.npz: means at t_mid [k, 3], velocities units/s, scales (activated), quats (w, x,"
                     " y, z), opacities, colors (RGB), moving (0/1);"
                     " position at time t = means + velocities (t - t_mid)",
        "background": [0.0, 0.0, 0.0],
        **({} if floor is None else {"noise_floor_psnr": floor, "noise_floor": "held-out PSNR (dB) of the noise-free"
            " frames against the written ones on cam00 at full resolution: a perfect model's score (a loader that"
            " downsamples by d averages d² pixels, lowering the noise SD by d)"}),
    }, indent=2))
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m harness.run.known_size --out DIR [--seed N] [--set k=500 ...]``: write the scene; exit status 2 on bad
    input (``harness.run.writer_cli``)."""
    from harness.run import writer_cli

    return writer_cli.main("python -m harness.run.known_size", __doc__.split("\n\n")[0], generate, "k=500", argv)


if __name__ == "__main__":
    raise SystemExit(main())
