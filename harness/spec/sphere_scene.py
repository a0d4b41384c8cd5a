"""The sphere scene, as a study file names it: its arguments and their checks.

``synth: {preset: spheres, seed: 3, n_cameras: 6, missing: 2, ...}`` (``harness.run.spheres``
ray-casts and writes it); the specification lives here so that the study-file checks
(``spec.synth``) know it without importing the run wing.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from ftgspp.errors import InputError

PRESET = "spheres"


@dataclass(frozen=True)
class SphereSceneConfig:
    """The knobs of a sphere scene; everything written is a deterministic function of them.

    The rig is ``n_cameras`` slots on a horizontal arc around the target, ``spacing_deg`` apart
    as seen from the target; the middle slot is ``cam00`` (the held-out camera, as in DyNeRF),
    the others are ``cam01``... from left to right. ``missing`` names one slot (its number, 1 ..
    n_cameras - 1) whose video is not written: the rig has a gap there."""

    seed: int = 0
    layout: str = "dynerf"
    preset: str = PRESET
    n_cameras: int = 8  # rig slots, the missing one included
    missing: int | None = None  # camNN left out of the rig (None: every slot is written)
    spacing_deg: float = 8.0  # angle between neighbouring slots, seen from the target
    radius: float = 4.0  # camera distance to the target (world units)
    elevation_deg: float = 10.0  # the rig looks down at the target by this angle
    hfov_deg: float = 50.0
    width: int = 96
    height: int = 72
    n_frames: int = 12
    fps: float = 30.0
    n_still: int = 3  # spheres that never move
    n_moving: int = 2  # spheres in straight-line motion at ``speed``
    speed: float = 0.6  # units/s
    texture: float = 0.0  # 0: smooth Lambertian spheres; a: albedo x (1 + a sin sin sin) in sphere-local space
    texture_freq: float = 6.0  # the solid sine pattern's angular frequency, per sphere radius
    color_gain: float = 0.0  # per camera and channel: gain 1 + U(-g, g)
    color_offset: float = 0.0  # per camera and channel: offset U(-o, o), the image in [0, 1]
    noise: float = 0.0  # Gaussian sensor noise sigma, the image in [0, 1]
    supersample: int = 3  # s x s rays per pixel for the colours (depth: the pixel centre)


def resolve(args: dict[str, Any]) -> SphereSceneConfig:
    """The config of study-file arguments (``InputError`` naming the first bad one)."""
    own = {f.name for f in fields(SphereSceneConfig)}
    bad = sorted(set(args) - own)
    if bad:
        raise InputError(PRESET, f"unknown argument(s) {', '.join(bad)} (known: {', '.join(sorted(own))})")
    try:
        cfg = SphereSceneConfig(**args)
    except TypeError as err:
        raise InputError(PRESET, str(err)) from None
    number = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)  # noqa: E731
    for f in fields(SphereSceneConfig):
        v = getattr(cfg, f.name)
        if f.name in ("layout", "preset") or (f.name == "missing" and v is None):
            continue
        if not number(v):
            raise InputError(PRESET, f"{f.name} must be a number, got {v!r}")
    checks = [
        ("layout", cfg.layout == "dynerf", f"writes the dynerf layout only, not '{cfg.layout}'"),
        ("n_cameras", isinstance(cfg.n_cameras, int) and cfg.n_cameras >= 3, "needs a whole number >= 3"),
        ("missing", cfg.missing is None or (isinstance(cfg.missing, int) and 1 <= cfg.missing < cfg.n_cameras),
         f"must be a camera number 1..{cfg.n_cameras - 1} (cam00 is held out) or null"),
        ("spacing_deg", 0 < cfg.spacing_deg * (cfg.n_cameras - 1) < 180, "the arc must span (0, 180) degrees"),
        ("radius", cfg.radius > 0, "must be > 0"),
        ("elevation_deg", -60 <= cfg.elevation_deg <= 60, "must be in [-60, 60]"),
        ("hfov_deg", 10 <= cfg.hfov_deg <= 120, "must be in [10, 120]"),
        ("width", isinstance(cfg.width, int) and cfg.width >= 16 and cfg.width % 2 == 0, "must be even and >= 16"),
        ("height", isinstance(cfg.height, int) and cfg.height >= 16 and cfg.height % 2 == 0, "must be even and >= 16"),
        ("n_frames", isinstance(cfg.n_frames, int) and cfg.n_frames >= 2, "needs a whole number >= 2"),
        ("fps", cfg.fps > 0, "must be > 0"),
        ("n_still", isinstance(cfg.n_still, int) and cfg.n_still >= 0, "needs a whole number >= 0"),
        ("n_moving", isinstance(cfg.n_moving, int) and cfg.n_moving >= 0, "needs a whole number >= 0"),
        ("spheres", 1 <= cfg.n_still + cfg.n_moving <= 20, "n_still + n_moving must be 1..20"),
        ("speed", cfg.speed >= 0, "must be >= 0"),
        ("texture", 0 <= cfg.texture <= 1, "must be in [0, 1]"),
        ("texture_freq", cfg.texture_freq > 0, "must be > 0"),
        ("color_gain", 0 <= cfg.color_gain < 1, "must be in [0, 1)"),
        ("color_offset", 0 <= cfg.color_offset < 0.5, "must be in [0, 0.5)"),
        ("noise", cfg.noise >= 0, "must be >= 0"),
        ("supersample", isinstance(cfg.supersample, int) and 1 <= cfg.supersample <= 8, "needs a whole number 1..8"),
    ]
    for name, ok, problem in checks:
        if not ok:
            raise InputError(PRESET, f"{name}: {problem}")
    return cfg
