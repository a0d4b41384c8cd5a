"""The torch device a run trains on, from ``TrainConfig.device`` (``auto`` | ``cpu`` | ``cuda``).

    device = resolve_device("auto")   # cuda when a GPU is visible, else cpu
"""

from __future__ import annotations

import torch

from ftgspp.errors import InputError


def resolve_device(name: str) -> torch.device:
    """``auto`` is CUDA when available, else CPU; ``InputError`` for CUDA on a machine without it
    or a name torch does not know."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError as err:
        raise InputError("device", str(err).splitlines()[0]) from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise InputError("device", f"{name} requested but no CUDA device is available")
    return device
