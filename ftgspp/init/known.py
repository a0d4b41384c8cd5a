"""Initial points from a scene's true Gaussians, perturbed: the control of the budget finder.

``init.matcher=known`` reads ``known_size.npz`` beside the scene's videos (the true Gaussians of
a scene of known size, written by harness/run/known_size.py) instead of matching views, so that a
run shows what the optimiser reaches at the true count K when it starts near the answer. The
perturbation is fixed and stated here (seeded by the init seed):

- centres: + N(0, (``POSITION_JITTER`` · s)²) per axis, s the Gaussian's mean true scale;
- colours: + N(0, ``COLOUR_JITTER``²) per channel, clipped to [0, 1];
- velocities exact; every time centre at the clip's middle, where the file's centres are;
- scale: isotropic, the mean of its three true scales (``spacing`` = s / ``init.scale_factor``,
  so that the model's initial scale, ``init.scale_factor`` × spacing, is s);
- rotation, opacity and lifetime: the ordinary initialisation's (identity, ``init.opacity``,
  ``init.duration``; a lifetime that covers the clip needs ``init.duration`` of about its length;
  ``study budget --control`` sets 1 s and the true opacities' mean, 0.85: harness/cli/budget.py).

``init.random_points`` is not used.

``ftgspp.init.points.initialize`` fits the K points to the budget as it fits matched points (a
random subset, or jittered copies), so a budget of K starts from every true Gaussian once.

    ftgspp train data.path=data/synth/budget_known_size init.matcher=known init.duration=1 init.opacity=0.85 budget=500
"""

from __future__ import annotations

import numpy as np

from ftgspp.config import InitConfig
from ftgspp.data.scene import Scene
from ftgspp.errors import InputError

TRUTH_FILE = "known_size.npz"
POSITION_JITTER = 0.5  # centre offsets' SD, in units of the Gaussian's own mean scale
COLOUR_JITTER = 0.05  # colour offsets' SD (RGB in [0, 1])


def true_points(scene: Scene, cfg: InitConfig, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The scene's true Gaussians as initial points, perturbed (module docstring): ``means``,
    ``colors`` ``[K, 3]``, ``times`` ``[K]``, ``velocities`` ``[K, 3]``, ``spacing`` and
    ``union_spacing`` ``[K]``, float32, and ``keyframe`` ``[K]`` (all 0: one set at the clip's
    middle), the fields of ``InitPoints``."""
    path = scene.root / TRUTH_FILE
    if not path.is_file():
        raise InputError("init.matcher", f"'known' needs the true Gaussians in {path} (a scene of known size,"
                                         " harness/run/known_size.py)")
    truth = np.load(path)
    scale = truth["scales"].astype(np.float64).mean(axis=1)  # [K]
    k = len(scale)
    means = truth["means"] + rng.normal(size=(k, 3)) * (POSITION_JITTER * scale[:, None])
    colors = np.clip(truth["colors"] + rng.normal(0.0, COLOUR_JITTER, size=(k, 3)), 0.0, 1.0)
    return {
        "means": means.astype(np.float32),
        "colors": colors.astype(np.float32),
        "times": np.full(k, float(truth["t_mid"]), dtype=np.float32),
        "velocities": truth["velocities"].astype(np.float32),
        "spacing": (scale / cfg.scale_factor).astype(np.float32),
        "union_spacing": (scale / cfg.scale_factor).astype(np.float32),  # one set: no union to search
        "keyframe": np.zeros(k, dtype=np.int64),
    }

