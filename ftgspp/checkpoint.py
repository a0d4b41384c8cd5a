"""A trained model on disk: what ``train`` leaves in its run folder and ``ftgspp diagnose`` reads.

- ``config.json``: the run's ``TrainConfig`` (``dataclasses.asdict``);
- ``gaussians.pt``: the raw (not activated) parameters, ``{name: tensor}`` on the CPU;
- ``color_correction.npy`` ``[C, 3, 3]`` and ``color_bias.npy`` ``[C, 3]``: the per-camera
  colour transforms learned during training (runs with colour correction only; evaluation
  never applies them).

The resumable training state (optimizer, sampler, ...) is ``checkpoint.pt`` (``train_state``).

    save_config(cfg, out_dir)            # when training starts
    save_model(model, cc, out_dir)       # when it ends
    model, cfg = load_run(out_dir)
    scene = run_scene(cfg, data=None)    # the run's scene (or the folder ``data`` names)
    cc = load_colour_correction(out_dir, cfg, len(scene.train_ids))
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from ftgspp.colour_correction import ColorCorrection
from ftgspp.config import TrainConfig, train_config_from_dict
from ftgspp.data.load import load_scene
from ftgspp.data.scene import Scene
from ftgspp.errors import InputError
from ftgspp.methods import method_class
from ftgspp.methods.base import DynamicGaussians

CONFIG = "config.json"
GAUSSIANS = "gaussians.pt"
COLOR_MATRICES = "color_correction.npy"
COLOR_BIAS = "color_bias.npy"


def save_config(cfg: TrainConfig, out_dir: Path) -> None:
    """Write ``cfg`` as ``out_dir/config.json``."""
    (out_dir / CONFIG).write_text(json.dumps(asdict(cfg), indent=2))


def save_model(model: DynamicGaussians, cc: ColorCorrection | None, out_dir: Path) -> None:
    """Write the model's parameters and, when there is one, the learned colour correction."""
    torch.save({k: v.detach().cpu() for k, v in model.params.items()}, out_dir / GAUSSIANS)
    if cc is not None:
        np.save(out_dir / COLOR_MATRICES, cc.matrices().cpu().numpy())
        np.save(out_dir / COLOR_BIAS, cc.biases().cpu().numpy())


def load_run(run_dir: str | Path, device: str = "cpu") -> tuple[DynamicGaussians, TrainConfig]:
    """The model (on ``device``, of the run's method) and config of a finished run; ``InputError``
    if either is missing."""
    run = Path(run_dir)
    for name in (CONFIG, GAUSSIANS):
        if not (run / name).is_file():
            raise InputError(run / name, "not found (is this a finished training run?)")
    try:
        cfg = train_config_from_dict(json.loads((run / CONFIG).read_text()))
    except (json.JSONDecodeError, TypeError) as err:
        raise InputError(run / CONFIG, f"unreadable: {err}") from err
    params = torch.load(run / GAUSSIANS, map_location=device, weights_only=True)
    return method_class(cfg.model.method)(params, cfg.model), cfg


def load_colour_correction(run_dir: str | Path, cfg: TrainConfig, n_cameras: int,
                           device: str | torch.device = "cpu") -> ColorCorrection | None:
    """The colour correction a run learned (``None`` for a run without one): the transforms it
    saved, in ``cfg.model.cc_gauge``; the identity when the run has one but saved none."""
    if not cfg.model.color_correction:
        return None
    cc = ColorCorrection(n_cameras, device, cfg.model.cc_gauge)
    run = Path(run_dir)
    if (run / COLOR_MATRICES).is_file() and (run / COLOR_BIAS).is_file():
        matrices = torch.from_numpy(np.load(run / COLOR_MATRICES)).to(device, torch.float32)  # [C, 3, 3]
        biases = torch.from_numpy(np.load(run / COLOR_BIAS)).to(device, torch.float32)  # [C, 3]
        if matrices.shape != cc.delta.shape or biases.shape != cc.bias.shape:
            raise InputError(run / COLOR_MATRICES, f"transforms of {matrices.shape[0]} cameras, but the scene has"
                             f" {n_cameras} training cameras")
        with torch.no_grad():  # saved: the transforms in use, I + ΔM and b (a no-op in either gauge)
            cc.delta.copy_(matrices - torch.eye(3, device=device))
            cc.bias.copy_(biases)
    return cc


def run_scene(cfg: TrainConfig, data: str | None = None) -> Scene:
    """The scene a run trained on (``cfg.data``), or the folder ``data`` when given;
    ``InputError`` when the run's relative scene path does not exist here."""
    if data:
        cfg.data.path = data
    elif not Path(cfg.data.path).is_dir():  # a relative path of a study run made elsewhere
        raise InputError("data.path", f"{cfg.data.path}: no such folder here (the run's scene path is relative to"
                         " where it was trained); give the scene with --data DIR")
    return load_scene(cfg.data)
