"""The true Gaussians of a scene drawn from Gaussians, as a model the diagnostics can score.

A scene whose frames were rendered from known Gaussians (the harness's known-size scene,
``harness/run/known_size.py``, with ``ground_truth: true``) keeps them in
``gt/gaussians.npz``: ``means [K, 3]`` at time ``t_mid``, ``velocities [K, 3]`` (units/s,
straight lines), ``scales [K, 3]`` (activated), ``quats [K, 4]`` (w, x, y, z), ``opacities
[K]`` (constant over the clip), ``colors [K, 3]`` (RGB), ``moving [K]`` (0/1) and ``t_mid``.
Each true Gaussian is one object: it never hands its pixels to another. ``true_model`` loads
them as a FreeTimeGS model (``FreeTimeGaussians``: the same centre, velocity, shape, opacity
and colour, a temporal scale so long that the opacity is constant over any clip), so the
scores measured on a trained model can be measured, the same way, on the truth: its role
switching (``motion_role_switch_gt``) is the level a model without role switching reaches
under that measure — not 0, since true Gaussians overlap and pass each other.

    truth = load_true_model(scene, device)          # None without gt/gaussians.npz
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ftgspp.config import ModelConfig
from ftgspp.data.scene import Scene
from ftgspp.methods.freetime import SH_C0, FreeTimeGaussians

GAUSSIANS_FILE = "gaussians.npz"
FOREVER_S = 1.0e6  # temporal standard deviation of a true Gaussian: φ(t) = 1 to float precision on any clip


def true_model(g: dict[str, np.ndarray], device: torch.device | str = "cpu") -> FreeTimeGaussians:
    """A FreeTimeGS model (degree-0 colour, no gate, unbounded temporal scale) with one Gaussian
    per true one of ``g`` (the arrays of ``gt/gaussians.npz``), centred in time at ``t_mid``."""
    f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32, device=device)  # noqa: E731
    k = len(g["means"])
    o = f32(g["opacities"]).clamp(1e-6, 1 - 1e-6)
    params = {
        "means": f32(g["means"]),
        "times": torch.full((k,), float(g["t_mid"]), device=device),
        "durations": torch.full((k,), float(np.log(FOREVER_S)), device=device),
        "velocities": f32(g["velocities"]),
        "scales": torch.log(f32(g["scales"])),
        "quats": f32(g["quats"]),
        "opacities": torch.log(o / (1 - o)),
        "sh0": ((f32(g["colors"]) - 0.5) / SH_C0)[:, None, :],
        "shN": torch.zeros(k, 0, 3, device=device),
        "gates": torch.zeros(k, device=device),
    }
    return FreeTimeGaussians(params, ModelConfig(sh_degree=0, max_duration=None, gate=False))


def load_true_model(scene: Scene, device: torch.device | str = "cpu") -> FreeTimeGaussians | None:
    """The scene's true Gaussians as a model (``true_model``), or None when ``gt/gaussians.npz``
    is absent (every scene not drawn from Gaussians)."""
    if scene.ground_truth is None:
        return None
    path = Path(scene.ground_truth) / GAUSSIANS_FILE
    if not path.is_file():
        return None
    with np.load(path) as z:
        return true_model({k: z[k] for k in z.files}, device)
