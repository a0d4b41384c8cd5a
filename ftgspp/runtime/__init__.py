"""The environment a training run needs, applied in this process or in a child process.

- ``determinism``: what a run's bits depend on, and the portable mode that pins it;
- ``child``: training in a child process started with the environment the run needs
  (``needs_child`` / ``train_in_child``), the one way a run gets another environment;
- ``jit``: the Numba options the kernels compile with and the threading layer;
- ``device``: the torch device ``TrainConfig.device`` names.

``enter(cfg)`` applies a run's environment in this process, once it is the right one
(``needs_child(cfg)`` is False)::

    if needs_child(cfg):
        return train_in_child(cfg, tracker)
    env = enter(cfg)   # env.device, env.domain (recorded as determinism.json), env.torch_threads
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ftgspp.config import TrainConfig
from ftgspp.errors import InputError
from ftgspp.runtime.child import check_dispatch, needs_child, train_in_child
from ftgspp.runtime.determinism import apply_runtime, determinism_domain
from ftgspp.runtime.device import resolve_device
from ftgspp.runtime.jit import configure_numba

__all__ = ["RunEnvironment", "enter", "needs_child", "train_in_child"]


@dataclass(frozen=True)
class RunEnvironment:
    """What ``enter`` set up: where the run trains and what its bits depend on."""

    device: torch.device
    domain: dict[str, str]  # determinism_domain(): what the bits depend on, with its ``id``
    torch_threads: int  # torch's thread count for the run


def enter(cfg: TrainConfig) -> RunEnvironment:
    """Apply ``cfg``'s run environment in this process: check the dispatch, set torch's threads,
    oneDNN and OpenCV for its determinism mode, choose Numba's threading layer, resolve the device.

    ``InputError`` for a setting this process cannot apply (bad dispatch or mode, portable mode
    without its environment, an unavailable device).
    """
    check_dispatch(cfg)
    try:
        threads = apply_runtime(cfg.determinism, cfg.threads)
    except (RuntimeError, ValueError) as err:
        raise InputError("determinism", str(err)) from None
    configure_numba()
    domain = determinism_domain(cfg.determinism, cfg.threads)
    return RunEnvironment(device=resolve_device(cfg.device), domain=domain, torch_threads=threads)
