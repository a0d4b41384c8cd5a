"""The mutable state of one training run, in one object that saves and restores itself.

``TrainState`` holds what changes while a run trains: the Gaussians, the colour
correction, one Adam over every parameter group, the relocation statistics, the frame
sampler and the random generators, the step and the training seconds. Learning rates are
derived from the step (``set_learning_rates``), so there is no scheduler state to keep.
``state_dict()`` / ``load_state_dict()`` make a checkpoint and a resume one call each, as
PyTorch modules and gsplat strategies do.

    state = TrainState.create(cfg, scene, device)
    ... train ...
    state.save(out_dir / "checkpoint.pt")
    state = TrainState.create(cfg, scene, device); state.load(out_dir / "checkpoint.pt")
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ftgspp.colour_correction import ColorCorrection
from ftgspp.config import LearningRates, TrainConfig
from ftgspp.data.scene import Scene
from ftgspp.errors import InputError
from ftgspp.init import initialize
from ftgspp.methods import method_class
from ftgspp.methods.base import DynamicGaussians
from ftgspp.strategy import Relocator

log = logging.getLogger("ftgspp.train")

# model.init_spacing -> the InitPoints field the initial scales come from (ftgspp/init/spacing.py)
INIT_SPACINGS = {None: "spacing", "keyframe": "spacing", "union": "union_spacing"}
CHECKPOINT_FORMAT = 2  # 1: one Adam per group and LR schedulers (before the state object)


def scene_extent(scene: Scene) -> float:
    """Radius of the training cameras around their centroid, × 1.1 (the 3DGS convention).

    Held-out cameras are left out: they must not influence training (here, the learning
    rates of means and velocities)."""
    centres = np.stack([scene.cameras[i].center for i in scene.train_ids])
    return float(1.1 * np.linalg.norm(centres - centres.mean(0), axis=1).max())


def build_model(cfg: TrainConfig, scene: Scene, device: torch.device, stats: dict | None = None) -> DynamicGaussians:
    """Initialise the method's Gaussians (``model.method``) from the scene's initial point set
    (seeded by ``init.fixed_seed`` or the run seed), their scales from the spacing
    ``model.init_spacing`` names (``INIT_SPACINGS``);
    ``stats`` (when given) receives what the initial point set is made of (``InitPoints.stats``)."""
    init_seed = cfg.seed if cfg.init.fixed_seed is None else cfg.init.fixed_seed
    pts = initialize(scene, cfg.init, cfg.budget, seed=init_seed)
    if stats is not None:
        stats.update(pts.stats)
    spacing = getattr(pts, INIT_SPACINGS[cfg.model.init_spacing])
    return method_class(cfg.model.method).from_points(
        pts.means, pts.colors, pts.times, pts.velocities, spacing, cfg.model, cfg.init, device
    )


def learning_rates(model: DynamicGaussians, lr: LearningRates) -> dict[str, float]:
    """Each optimised parameter's rate before ``lr.scale`` and the scene extent, by name.

    The rate of a parameter is under its name or the key ``LR_KEYS`` maps it to: the
    ``LearningRates`` field of that key where there is one (the rates every method shares, and
    the options of FreeTimeGS's and STGS's own), else ``lr.method[key]``, else the method's
    ``LEARNING_RATES[key]``. A key with none of them, or an ``lr.method`` key that is a field or
    that the method does not use, is a one-line ``InputError``."""
    fields = {f.name for f in dataclasses.fields(lr) if f.type in ("float", float)}
    keys = {name: model.LR_KEYS.get(name, name) for name in model.params if name not in model.frozen()}
    for key in lr.method:
        if key in fields:
            raise InputError(f"lr.method.{key}", f"'{key}' has an option of its own: set lr.{key}")
        if key not in keys.values():
            raise InputError(f"lr.method.{key}", f"{type(model).__name__} has no rate '{key}'"
                             f" (its parameters' rates: {', '.join(sorted(set(keys.values())))})")
    rates = {}
    for name, key in keys.items():
        if key in fields:
            rates[name] = getattr(lr, key)
        elif key in lr.method or key in model.LEARNING_RATES:
            rates[name] = lr.method.get(key, model.LEARNING_RATES.get(key))
        else:
            raise InputError("lr", f"no learning rate for the parameter '{name}' of {type(model).__name__}"
                             f" (no '{key}' in its LEARNING_RATES, nor in LearningRates; or map it in LR_KEYS)")
    return rates


def make_optimizer(
    model: DynamicGaussians, cc: ColorCorrection | None, cfg: TrainConfig, extent: float
) -> torch.optim.Adam:
    """One Adam over every parameter group (``group["name"]`` says which), fused on CPU and CUDA.

    Learning rates are ``learning_rates`` × ``lr.scale``, × the scene extent for the method's
    ``EXTENT_SCALED`` parameters (FreeTimeGS: means and velocities); ``group["decays"]`` marks the
    groups whose rate decays over training (``DECAYING``). The method's ``frozen()`` parameters
    are left out. The colour correction's group gets gradients only once it is switched on; Adam
    skips parameters without a gradient, so its moments start then.
    """
    rates = learning_rates(model, cfg.lr)
    groups = []
    for name, p in model.params.items():
        if name not in rates:  # frozen
            p.requires_grad_(False)
            continue
        lr = rates[name] * cfg.lr.scale * (extent if name in model.EXTENT_SCALED else 1.0)
        groups.append({"params": [p], "lr": lr, "initial_lr": lr, "name": name, "decays": name in model.DECAYING})
    if cc is not None:
        lr = cfg.lr.cc * (cfg.lr.scale if cfg.lr.cc_scaled else 1.0)
        groups.append({"params": list(cc.parameters()), "lr": lr, "initial_lr": lr, "name": "cc", "decays": False})
    return torch.optim.Adam(groups, eps=1e-15, fused=True)


def set_learning_rates(optimizer: torch.optim.Optimizer, step: int, cfg: TrainConfig) -> None:
    """Rates for iteration ``step`` (0-based): decaying groups reach ``means_final_ratio`` × their
    initial rate at ``cfg.iterations``, exponentially; the others stay constant."""
    fraction = step / max(cfg.iterations, 1)
    factor = cfg.lr.means_final_ratio**fraction
    for group in optimizer.param_groups:
        group["lr"] = group["initial_lr"] * (factor if group["decays"] else 1.0)


class FrameSampler:
    """Seeded shuffles of all (training camera, frame) pairs, one permutation per epoch."""

    def __init__(self, scene: Scene, generator: torch.Generator) -> None:
        self.pairs = [(c, f) for c in scene.train_ids for f in range(scene.n_frames)]
        self.generator = generator
        self.order: list[int] = []

    def next(self) -> tuple[int, int]:
        """The next (camera index, frame index) pair."""
        if not self.order:
            self.order = torch.randperm(len(self.pairs), generator=self.generator, device="cpu").tolist()
        return self.pairs[self.order.pop()]

    def state_dict(self) -> dict:
        return {"order": list(self.order), "generator": self.generator.get_state()}

    def load_state_dict(self, s: dict) -> None:
        self.order = list(s["order"])
        self.generator.set_state(s["generator"])


@dataclass
class TrainState:
    """Everything a run mutates; ``step`` iterations done after ``elapsed`` training seconds."""

    model: DynamicGaussians
    cc: ColorCorrection | None
    optimizer: torch.optim.Adam
    relocator: Relocator
    reloc_stats: dict[str, torch.Tensor]  # per-Gaussian accumulators (Relocator.initialize_state)
    sampler: FrameSampler
    reloc_gen: torch.Generator
    extent: float
    step: int = 0
    elapsed: float = 0.0
    relocated: int = 0  # Gaussians relocated so far (summed over relocation steps)
    init_stats: dict = field(default_factory=dict)  # the initial point set (written to init.json)

    @classmethod
    def create(cls, cfg: TrainConfig, scene: Scene, device: torch.device) -> "TrainState":
        """A fresh run: initialised Gaussians, identity colour correction, seeded generators."""
        relocator = Relocator(cfg.strategy)  # validates the strategy before the (slow) init
        init_stats: dict = {}
        model = build_model(cfg, scene, device, init_stats)
        cc = ColorCorrection(len(scene.train_ids), device, cfg.model.cc_gauge) if cfg.model.color_correction else None
        extent = scene_extent(scene)
        return cls(
            model=model,
            cc=cc,
            optimizer=make_optimizer(model, cc, cfg, extent),
            relocator=relocator,
            reloc_stats=relocator.initialize_state(len(model), device),
            sampler=FrameSampler(scene, torch.Generator().manual_seed(cfg.seed)),
            reloc_gen=torch.Generator().manual_seed(cfg.seed + 1),
            extent=extent,
            init_stats=init_stats,
        )

    def state_dict(self) -> dict:
        """Tensors on the CPU, plus the generators' and torch's global RNG states."""
        return {
            "format": CHECKPOINT_FORMAT,
            "step": self.step,
            "elapsed": self.elapsed,
            "relocated": self.relocated,
            "params": {k: v.detach().cpu() for k, v in self.model.params.items()},
            "cc": self.cc.state_dict() if self.cc is not None else None,
            "optimizer": self.optimizer.state_dict(),
            "reloc_stats": {k: v.cpu() for k, v in self.reloc_stats.items()},
            "sampler": self.sampler.state_dict(),
            "reloc_gen": self.reloc_gen.get_state(),
            "torch_rng": torch.get_rng_state(),
        }

    def load_state_dict(self, blob: dict) -> None:
        """Restore what ``state_dict`` saved (parameters copied in place, on their device)."""
        with torch.no_grad():
            for k, v in blob["params"].items():
                self.model.params[k].copy_(v)
        if self.cc is not None and blob["cc"] is not None:
            self.cc.load_state_dict(blob["cc"])
        self.optimizer.load_state_dict(blob["optimizer"])
        for k, v in blob["reloc_stats"].items():
            self.reloc_stats[k].copy_(v)
        self.sampler.load_state_dict(blob["sampler"])
        self.reloc_gen.set_state(blob["reloc_gen"])
        torch.set_rng_state(blob["torch_rng"])
        self.step, self.elapsed = int(blob["step"]), float(blob["elapsed"])
        self.relocated = int(blob.get("relocated", 0))

    def save(self, path: Path) -> None:
        """Write a checkpoint atomically (temporary file, then rename)."""
        tmp = path.with_suffix(".tmp")
        torch.save(self.state_dict(), tmp)
        tmp.replace(path)

    def load(self, path: Path) -> bool:
        """Resume from ``path``; False (and a warning) for a checkpoint of an older format."""
        blob = torch.load(path, weights_only=False)
        if blob.get("format") != CHECKPOINT_FORMAT:
            log.warning("%s was written by an older ftgspp (checkpoint format %s); training from the start",
                        path, blob.get("format", 1))
            return False
        self.load_state_dict(blob)
        return True
