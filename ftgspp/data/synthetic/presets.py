"""The knobs of a synthetic scene: ``SynthConfig``, its presets and their validation (``ftgspp synth``).

A preset sets the motion and event fields of ``SynthConfig``; ``resolve_config`` applies a
preset, then any overrides, and checks every value (one ``InputError`` naming the option).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from ftgspp.data.synthetic import layouts
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
