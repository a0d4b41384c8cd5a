"""Image metrics under every common convention, each named by its key.

    psnr            PSNR in dB, data range 1
    ssim1, ssim2    SSIM, 11x11 Gaussian window (sigma 1.5), data range 1 and 2
    dssim1, dssim2  (1 - ssim) / 2
    lpips_alex, lpips_vgg          LPIPS v0.1, images mapped to [-1, 1] (the correct input)
    lpips_alex_01, lpips_vgg_01    LPIPS fed [0, 1] images directly (the "3DGS convention")

Images are torch tensors [H, W, 3] or [B, H, W, 3] in [0, 1]. ``evaluate_images`` averages
per-frame values, as papers do. Metrics are looked up by name in ``METRICS``: a new metric
is one function plus one entry here, and one line in the harness's metric registry
(``harness/spec/metrics.py``: its label, decimals and direction, referencing the entry here).

Two SSIMs:

* ``ssim`` (evaluation) matches ``skimage.metrics.structural_similarity(a, b,
  channel_axis=-1, data_range=R, gaussian_weights=True, sigma=1.5,
  use_sample_covariance=False)``. skimage filters the whole image with a reflect-padded
  Gaussian, then averages the SSIM map with a 5-pixel border cropped away; the kept pixels
  are exactly those whose 11x11 window lies inside the image, so a 'valid' convolution
  gives the same numbers without any padding.
* ``ssim_same`` (training loss) is the 3DGS variant: zero-padded 'same' convolution,
  averaged over every pixel. Cheaper to reason about for gradients at the borders, and
  what 3DGS-style losses ``(1 - ssim)`` use. Its values differ slightly from ``ssim``.
  On float32 CPU tensors it runs as Numba kernels with a hand-written backward
  (``ftgspp.ssim_cpu``, same numbers to float32 rounding); otherwise as below.

Both are differentiable (separable Gaussian as two grouped ``conv2d``).

    ftgspp metrics IMG_A IMG_B [--json] [--weights DIR]   # every metric for one pair
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from dataclasses import dataclass
from functools import lru_cache, partial
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ftgspp.errors import InputError

log = logging.getLogger("ftgspp.image_metrics")

SSIM_WINDOW = 11
# Smallest image side each LPIPS backbone can take: AlexNet's second 3x3/2 max-pool needs
# sides >= 31 pixels, VGG16's four 2x2 pools need >= 16. Smaller images score NaN.
LPIPS_MIN_SIDE = {"alex": 31, "vgg": 16}
SSIM_SIGMA = 1.5
SSIM_K1, SSIM_K2 = 0.01, 0.03


# ----------------------------------------------------------------------------- helpers


def _as_batch(img: Tensor) -> tuple[Tensor, bool]:
    """[H, W, C] or [B, H, W, C] -> ([B, H, W, C], was_batched)."""
    if img.ndim == 3:
        return img.unsqueeze(0), False
    if img.ndim == 4:
        return img, True
    raise ValueError(f"expected an image [H, W, C] or [B, H, W, C], got shape {tuple(img.shape)}")


def _check_pair(a: Tensor, b: Tensor) -> None:
    if a.shape != b.shape:
        raise ValueError(f"image shapes differ: {tuple(a.shape)} vs {tuple(b.shape)}")


@lru_cache(maxsize=16)
def _gaussian_1d(size: int, sigma: float, dtype: torch.dtype, device: str) -> Tensor:
    """Normalised Gaussian taps [size], as scipy.ndimage (truncate so that r = size // 2)."""
    x = torch.arange(size, dtype=torch.float64, device="cpu") - size // 2
    w = torch.exp(-0.5 * (x / sigma) ** 2)
    return (w / w.sum()).to(dtype=dtype, device=device)


def _blur(x: Tensor, window: Tensor, padding: int) -> Tensor:
    """Separable Gaussian blur of every channel. x [N, C, H, W] -> [N, C, H', W']."""
    c, k = x.shape[1], window.numel()
    x = F.conv2d(x, window.view(1, 1, k, 1).expand(c, 1, k, 1), padding=(padding, 0), groups=c)
    return F.conv2d(x, window.view(1, 1, 1, k).expand(c, 1, 1, k), padding=(0, padding), groups=c)


def _ssim_maps(x: Tensor, y: Tensor, data_ranges: Sequence[float], padding: int) -> list[Tensor]:
    """SSIM maps at each data range. x, y [N, C, H, W] -> [N, C, H', W'] each (population
    covariances, Wang et al. 2004). The local moments do not depend on the range: one blur."""
    window = _gaussian_1d(SSIM_WINDOW, SSIM_SIGMA, x.dtype, str(x.device))
    c = x.shape[1]
    stats = _blur(torch.cat([x, y, x * x, y * y, x * y], dim=1), window, padding)
    mx, my, mxx, myy, mxy = stats.split(c, dim=1)
    vx, vy, vxy = mxx - mx * mx, myy - my * my, mxy - mx * my
    maps = []
    for data_range in data_ranges:
        c1, c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2
        maps.append(((2 * mx * my + c1) * (2 * vxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2)))
    return maps


def _ssim_map(x: Tensor, y: Tensor, data_range: float, padding: int) -> Tensor:
    """SSIM map at one data range (``_ssim_maps``)."""
    return _ssim_maps(x, y, (data_range,), padding)[0]


def _nchw(img: Tensor) -> Tensor:
    return img.permute(0, 3, 1, 2)


# ----------------------------------------------------------------------------- PSNR / SSIM


def psnr(a: Tensor, b: Tensor) -> Tensor:
    """PSNR in dB, data range 1. a, b [H, W, C] -> scalar, or [B, H, W, C] -> [B]."""
    _check_pair(a, b)
    (a, batched), (b, _) = _as_batch(a), _as_batch(b)
    mse = (a - b).pow(2).flatten(1).mean(dim=1)
    out = -10.0 * torch.log10(mse)
    return out if batched else out[0]


def ssim(a: Tensor, b: Tensor, data_range: float = 1.0) -> Tensor:
    """Evaluation SSIM (skimage-compatible, see module doc). [H, W, C] -> scalar, [B, H, W, C] -> [B]."""
    return ssims(a, b, (data_range,))[0]


def ssims(a: Tensor, b: Tensor, data_ranges: Sequence[float]) -> list[Tensor]:
    """``ssim`` at each of ``data_ranges`` from one computation of the local moments: each the
    same value as ``ssim`` at that range, for about the cost of one."""
    _check_pair(a, b)
    (a, batched), (b, _) = _as_batch(a), _as_batch(b)
    if min(a.shape[1], a.shape[2]) < SSIM_WINDOW:
        raise ValueError(f"SSIM needs images of at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels, got {tuple(a.shape[1:3])}")
    means = [m.flatten(1).mean(dim=1) for m in _ssim_maps(_nchw(a), _nchw(b), data_ranges, padding=0)]
    return means if batched else [m[0] for m in means]


def ssim_same(a: Tensor, b: Tensor, data_range: float = 1.0) -> Tensor:
    """Training-loss SSIM (3DGS: zero-padded 'same' window, mean over all pixels).

    a, b [H, W, C] -> scalar or [B, H, W, C] -> [B]. Use ``1 - ssim_same`` as the D-SSIM loss.
    """
    _check_pair(a, b)
    (a, batched), (b, _) = _as_batch(a), _as_batch(b)
    if _fast_ssim_applies(a, b):
        from ftgspp.ssim_cpu import ssim_same_cpu

        taps = _gaussian_1d(SSIM_WINDOW, SSIM_SIGMA, torch.float32, "cpu").numpy()
        c1, c2 = (SSIM_K1 * data_range) ** 2, (SSIM_K2 * data_range) ** 2
        out = ssim_same_cpu(a, b, taps, c1, c2)
    else:
        out = _ssim_map(_nchw(a), _nchw(b), data_range, padding=SSIM_WINDOW // 2).flatten(1).mean(dim=1)
    return out if batched else out[0]


def _fast_ssim_applies(a: Tensor, b: Tensor) -> bool:
    """Whether ``ssim_same`` can use the Numba kernels (float32 CPU tensors, Numba importable)."""
    if not (a.dtype == b.dtype == torch.float32 and a.device.type == b.device.type == "cpu"):
        return False
    try:
        import ftgspp.ssim_cpu  # noqa: F401
    except ImportError:
        return False
    return True


def dssim(a: Tensor, b: Tensor, data_range: float = 1.0) -> Tensor:
    """(1 - ssim) / 2 with the evaluation SSIM."""
    return dssim_from_ssim(ssim(a, b, data_range))


def dssim_from_ssim(s: Tensor) -> Tensor:
    """D-SSIM from an SSIM value: (1 - s) / 2 (``dssim``'s formula, which evaluation reuses)."""
    return (1.0 - s) / 2.0


def lpips_distance(model: torch.nn.Module, a: Tensor, b: Tensor, zero_one: bool = False) -> Tensor:
    """LPIPS between [0, 1] images. [H, W, 3] -> scalar, [B, H, W, 3] -> [B].

    ``zero_one=False`` maps the images to [-1, 1] first (correct); ``True`` feeds them as
    they are (3DGS convention). Differentiable, so usable as a training loss.
    """
    _check_pair(a, b)
    (a, batched), (b, _) = _as_batch(a), _as_batch(b)
    x0, x1 = _nchw(a), _nchw(b)
    if not zero_one:
        x0, x1 = 2.0 * x0 - 1.0, 2.0 * x1 - 1.0
    out = model(x0, x1)
    return out if batched else out[0]


# ----------------------------------------------------------------------------- registry

# pred, gt [B, H, W, 3]; lpips models by net name -> per-frame values [B]
MetricFn = Callable[[Tensor, Tensor, Mapping[str, torch.nn.Module]], Tensor]


@dataclass(frozen=True)
class ImageMetric:
    """A named evaluator: ``fn`` plus what it needs and how the ``ftgspp metrics`` command describes it."""

    fn: MetricFn
    description: str
    lpips_net: str | None = None  # the LPIPS model it needs, if any


def _psnr(p: Tensor, g: Tensor, _: Mapping[str, torch.nn.Module]) -> Tensor:
    return psnr(p.double(), g.double())


def colour_aligned(pred: Tensor, gt: Tensor) -> Tensor:
    """``pred`` after the least-squares affine colour map onto ``gt`` (per image of the batch):
    ``[pred, 1] A`` with ``A`` [4, 3] minimising ‖[pred, 1] A − gt‖², clamped to [0, 1].
    A render that differs from the ground truth by a global colour transform scores as if it
    did not (the colour-corrected metrics some 3DGS evaluations offer). [B, H, W, 3] -> same
    (fitted in float64, the same bits on every call and machine: ``ftgspp.colour_alignment``)."""
    from ftgspp.colour_alignment import colour_aligned_np

    p = pred.detach().to("cpu", torch.float64).reshape(pred.shape[0], -1, 3).numpy()
    g = gt.detach().to("cpu", torch.float64).reshape(gt.shape[0], -1, 3).numpy()
    out = np.stack([colour_aligned_np(pi, gi) for pi, gi in zip(p, g)])
    return torch.from_numpy(out).reshape(pred.shape).to(device=pred.device, dtype=pred.dtype)


def _psnr_aligned(p: Tensor, g: Tensor, _: Mapping[str, torch.nn.Module]) -> Tensor:
    return psnr(colour_aligned(p.double(), g.double()), g.double())


def _ssim(p: Tensor, g: Tensor, _: Mapping[str, torch.nn.Module], data_range: float) -> Tensor:
    return ssim(p.double(), g.double(), data_range)


def _dssim(p: Tensor, g: Tensor, _: Mapping[str, torch.nn.Module], data_range: float) -> Tensor:
    return dssim(p.double(), g.double(), data_range)


_warned_small: set[tuple[str, int, int]] = set()


def _lpips(p: Tensor, g: Tensor, models: Mapping[str, torch.nn.Module], net: str, zero_one: bool) -> Tensor:
    height, width = p.shape[1], p.shape[2]
    if min(height, width) < LPIPS_MIN_SIDE[net]:  # the network cannot take it: NaN, one warning
        if (net, height, width) not in _warned_small:
            _warned_small.add((net, height, width))
            log.warning("LPIPS-%s needs images of at least %dx%d pixels, got %dx%d: lpips_%s is NaN",
                        net, LPIPS_MIN_SIDE[net], LPIPS_MIN_SIDE[net], width, height, net)
        return torch.full((p.shape[0],), float("nan"), dtype=torch.float64)
    model = models[net]
    device = next(model.parameters()).device
    return lpips_distance(model, p.float().to(device), g.float().to(device), zero_one)


_SSIM_DESC = "11x11 Gaussian window, sigma 1.5, data range {}"
METRICS: dict[str, ImageMetric] = {
    "psnr": ImageMetric(_psnr, "dB, data range 1"),
    "psnr_cc": ImageMetric(_psnr_aligned, "dB, after a least-squares affine colour map of the render onto the ground truth"),
    "ssim1": ImageMetric(partial(_ssim, data_range=1.0), _SSIM_DESC.format(1)),
    "ssim2": ImageMetric(partial(_ssim, data_range=2.0), _SSIM_DESC.format(2)),
    "dssim1": ImageMetric(partial(_dssim, data_range=1.0), "(1 - ssim1) / 2"),
    "dssim2": ImageMetric(partial(_dssim, data_range=2.0), "(1 - ssim2) / 2"),
    "lpips_alex": ImageMetric(partial(_lpips, net="alex", zero_one=False), "AlexNet, inputs mapped to [-1, 1] (correct)", "alex"),
    "lpips_vgg": ImageMetric(partial(_lpips, net="vgg", zero_one=False), "VGG16, inputs mapped to [-1, 1] (correct)", "vgg"),
    "lpips_alex_01": ImageMetric(partial(_lpips, net="alex", zero_one=True), "AlexNet, [0, 1] fed directly (3DGS convention)", "alex"),
    "lpips_vgg_01": ImageMetric(partial(_lpips, net="vgg", zero_one=True), "VGG16, [0, 1] fed directly (3DGS convention)", "vgg"),
}


# D-SSIM metrics and the SSIM each is computed from ((1 - ssim) / 2, as ``dssim`` does)
_FROM_SSIM = {"dssim1": "ssim1", "dssim2": "ssim2"}
_SSIM_RANGES = {"ssim1": 1.0, "ssim2": 2.0}  # what _ssim computes for each, in double precision


def available_metrics(lpips: Mapping[str, torch.nn.Module] | None = None) -> list[str]:
    """Names in ``METRICS`` that can be computed with the given LPIPS models."""
    models = lpips or {}
    return [name for name, m in METRICS.items() if m.lpips_net is None or m.lpips_net in models]


@torch.no_grad()
def evaluate_images(
    pred: Tensor,
    gt: Tensor,
    lpips: Mapping[str, torch.nn.Module] | None = None,
    names: list[str] | None = None,
) -> dict[str, float]:
    """Every metric (or ``names``) for pred vs gt, averaged over frames.

    pred, gt [H, W, 3] or [B, H, W, 3] in [0, 1]. ``lpips`` maps net names ("alex", "vgg")
    to ``ftgspp.lpips.LPIPS`` models (e.g. ``ftgspp.lpips.load_all()``); without it the
    LPIPS keys are left out. Frames are evaluated one at a time to bound memory.
    """
    _check_pair(pred, gt)
    (pred, _), (gt, _) = _as_batch(pred), _as_batch(gt)
    models = lpips or {}
    names = available_metrics(models) if names is None else names
    for name in names:
        if name not in METRICS:
            raise KeyError(f"unknown metric '{name}'; known: {sorted(METRICS)}")
        if METRICS[name].lpips_net is not None and METRICS[name].lpips_net not in models:
            raise KeyError(f"metric '{name}' needs the LPIPS '{METRICS[name].lpips_net}' model")
    sums = dict.fromkeys(names, 0.0)
    # the SSIMs these names need, all from one pass over each frame's local moments
    shared = [s for s in _SSIM_RANGES if s in names or any(_FROM_SSIM.get(n) == s for n in names)]
    for i in range(pred.shape[0]):
        p, g = pred[i : i + 1], gt[i : i + 1]
        values: dict[str, Tensor] = {}
        if shared:
            values.update(zip(shared, ssims(p.double(), g.double(), [_SSIM_RANGES[s] for s in shared])))
        for name in names:
            source = _FROM_SSIM.get(name)
            if source is not None:  # D-SSIM from this frame's SSIM (in ``shared``): one pass, not two
                values[name] = dssim_from_ssim(values[source])  # what dssim computes: the same bits
            elif name not in values:
                values[name] = METRICS[name].fn(p, g, models)
            sums[name] += float(values[name][0])
    return {name: total / pred.shape[0] for name, total in sums.items()}


# ----------------------------------------------------------------------------- CLI


def read_image(path: str | Path) -> Tensor:
    """Read an image file with OpenCV as RGB float [H, W, 3] in [0, 1]."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "image file not found")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(path, "cannot be read as an image")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = img[:, :, :3]  # drop alpha
    elif img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    if img.dtype == np.uint8:
        arr = img.astype(np.float32) / 255.0
    elif img.dtype == np.uint16:
        arr = img.astype(np.float32) / 65535.0
    elif img.dtype.kind == "f":
        arr = img.astype(np.float32)
    else:
        raise InputError(path, f"unsupported pixel type {img.dtype}")
    return torch.from_numpy(np.ascontiguousarray(arr[:, :, ::-1]))  # BGR -> RGB


def _format_value(value: float) -> str:
    return "inf" if math.isinf(value) else f"{value:.6f}"


def main_metrics(argv: list[str]) -> int:
    """``ftgspp metrics IMG_A IMG_B [--json] [--weights DIR]``: every metric for one pair."""
    from ftgspp.lpips import load_all, missing_message, weights_present

    parser = argparse.ArgumentParser(prog="ftgspp metrics", description="every image metric for a pair of images")
    parser.add_argument("img_a", type=Path, help="first image (e.g. the render)")
    parser.add_argument("img_b", type=Path, help="second image (e.g. the ground truth)")
    parser.add_argument("--json", action="store_true", help="print one JSON line instead of a table")
    parser.add_argument("--weights", type=Path, default=None, help="LPIPS weights directory")
    args = parser.parse_args(argv)

    a, b = read_image(args.img_a), read_image(args.img_b)
    if a.shape != b.shape:
        raise InputError(args.img_b, f"size {b.shape[1]}x{b.shape[0]} does not match {args.img_a} ({a.shape[1]}x{a.shape[0]})")
    if min(a.shape[0], a.shape[1]) < SSIM_WINDOW:
        raise InputError(args.img_a, f"images must be at least {SSIM_WINDOW}x{SSIM_WINDOW} pixels")

    models = load_all(args.weights) if weights_present(args.weights) else None
    values = evaluate_images(a, b, lpips=models)
    note = None if models else f"note: {missing_message(args.weights)} (LPIPS rows left out)"
    if args.json:
        print(json.dumps(values))
        if note:
            print(note, file=sys.stderr)
        return 0
    width = max(len(name) for name in values)
    print(f"{'metric':<{width}}  {'value':>12}  convention")
    for name, value in values.items():
        print(f"{name:<{width}}  {_format_value(value):>12}  {METRICS[name].description}")
    if note:
        print(note)
    return 0
