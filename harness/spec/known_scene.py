"""The scene of known size, as a study file names it: its arguments and their checks.

``synth: {preset: known_size, k: 500, ...}`` (``harness.run.known_size`` draws and writes it);
the specification lives here so that the study-file checks (``spec.synth``) and the reproduce
command (``spec.runs``) know it without importing the run wing.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from ftgspp.data.synthetic.presets import SynthConfig
from ftgspp.errors import InputError

PRESET = "known_size"


RIG_FIELDS = ("n_cameras", "n_frames", "fps", "width", "height", "hfov_deg", "arc_deg", "rig_radius")


@dataclass(frozen=True)
class KnownSizeConfig:
    """The knobs of a known-size scene; everything is a deterministic function of them. The
    cameras and the clip are the synthetic presets' (``rig``: a ``SynthConfig`` whose
    ``RIG_FIELDS`` a study may override)."""

    k: int = 500  # Gaussians that draw the scene
    moving_share: float = 0.25  # the share of them that moves (in straight lines)
    speed: float = 0.5  # units/s of every moving Gaussian
    sigma_px: float = 3.0  # typical blob size: standard deviation in pixels of a full-size view at the target
    # also write the held-out camera's ground truth (gt/: the true Gaussians, per-pixel carrier ids
    # of the moving ones, depth, scene flow, the noise-free frames) for the diagnostics' scores
    ground_truth: bool = False
    # sensor noise: per-pixel, per-channel Gaussian of this SD in 8-bit units before the 8-bit rounding
    # (0: noise-free, the scene before issue 56; 2: a perfect model's PSNR ≈ 20·log10(255/2) ≈ 42 dB)
    noise_sd: float = 0.0
    seed: int = 0
    layout: str = "dynerf"
    preset: str = PRESET
    rig: SynthConfig = field(default_factory=SynthConfig)


TARGET = np.array([0.0, 0.2, 1.4])  # where the rig looks (as the synthetic presets)
EYE_HEIGHT = -0.3


def resolve(args: dict[str, Any]) -> KnownSizeConfig:
    """The config of study-file arguments (``InputError`` for an unknown or bad one)."""
    own = {f.name for f in fields(KnownSizeConfig)} - {"rig"}
    bad = sorted(set(args) - own - set(RIG_FIELDS))
    if bad:
        known = ", ".join(sorted(own | set(RIG_FIELDS)))
        raise InputError(PRESET, f"unknown argument(s) {', '.join(bad)} (known: {known})")
    rig = replace(SynthConfig(), **{k: v for k, v in args.items() if k in RIG_FIELDS})
    cfg = KnownSizeConfig(**{k: v for k, v in args.items() if k in own}, rig=rig)
    if cfg.layout != "dynerf":
        raise InputError(PRESET, f"writes the dynerf layout only, not '{cfg.layout}'")
    if cfg.k < 1 or not 0 <= cfg.moving_share <= 1 or rig.n_cameras < 3 or rig.n_frames < 2:
        raise InputError(PRESET, "needs k >= 1, 0 <= moving_share <= 1, n_cameras >= 3 and n_frames >= 2")
    if not 0 <= cfg.noise_sd <= 64:
        raise InputError(PRESET, f"needs 0 <= noise_sd <= 64 (8-bit units), got {cfg.noise_sd}")
    if cfg.ground_truth and cfg.k >= 2**16 - 1:
        raise InputError(PRESET, f"ground_truth labels pixels with 16-bit ids: needs k < 65535, got {cfg.k}")
    return cfg
