"""Lifetimes of a trained model's Gaussians and how they split the scene into static and moving parts.

- **Effective lifetime** Δt(θ)/T of every Gaussian: how long its rendered opacity stays
  above θ, over the scene duration T. Without the gate this is ``model.lifetimes(θ)``; with
  it, φ(t) = g + (1 − g) a(t) ≥ θ/o needs a(t) ≥ a* = (θ/o − g)/(1 − g), so
  Δt = 2 s √(2 log(1/a*)), and a Gaussian with o·g ≥ θ is visible forever (Δt = ∞).
- **Where the groups lie** (scenes with ``gt/``): the share of long-lived Gaussians on
  static surfaces and of short-lived ones on moving objects (``lifetime_vs_objects``).
- **Rendered weight on the ground-truth masks** (``mask_weights``), scored as secret 1's
  partition contrast (share of the weight on moving-object pixels carried by short-lived
  Gaussians minus that share on static pixels; 1 = perfect split) and secret 2's role
  switch (how much the set of Gaussians rendering the moving objects changes from frame to
  frame; 0 = the same Gaussians throughout, 1 = a disjoint set every frame).

    frac = lifetime_fractions(model, theta=0.05, duration=scene.duration)   # [N] Δt/T
    short = subset_model(model, frac < 0.5)
"""

from __future__ import annotations

import numpy as np
import torch

from ftgspp.data.scene import Camera, Scene
from ftgspp.diagnostics.motion import GroundTruth
from ftgspp.methods.base import DynamicGaussians
from ftgspp.view import render_view


def effective_lifetimes(model: DynamicGaussians, theta: float) -> torch.Tensor:
    """Effective lifetime Δt(θ) in seconds, ``[N]`` (``inf`` for gated Gaussians that never fade)."""
    with torch.no_grad():
        return model.lifetimes(theta)


def lifetime_fractions(model: DynamicGaussians, theta: float, duration: float) -> np.ndarray:
    """Δt(θ)/T for every Gaussian, ``[N]`` float64 (``inf`` where it never fades)."""
    return effective_lifetimes(model, theta).detach().cpu().double().numpy() / float(duration)


def lifetime_histogram(fractions: np.ndarray, bins: int = 40, max_fraction: float = 2.0
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``(counts [bins], edges [bins + 1])`` of Δt/T on [0, max_fraction]; larger values
    (and ``inf``) are counted in the last bin."""
    return np.histogram(np.minimum(fractions, max_fraction), bins=bins, range=(0.0, max_fraction))


def subset_model(model: DynamicGaussians, keep: np.ndarray | torch.Tensor) -> DynamicGaussians:
    """A model with only the Gaussians where ``keep [N]`` is True (parameters copied)."""
    return model.subset(torch.as_tensor(keep, dtype=torch.bool, device=model.params["means"].device))


def lifetime_vs_objects(model: DynamicGaussians, scene: Scene, gts: dict[int, GroundTruth],
                        fractions: np.ndarray, split: float, depth_tol: float = 0.05) -> dict[str, float]:
    """Where the long- and short-lived Gaussians lie, from ground-truth object masks.

    A Gaussian is classified in the first camera of ``gts`` where its centre, at its own
    time clipped to the loaded range (nearest frame), projects inside the image with a depth
    within ``depth_tol`` (relative) of the ground-truth depth there (i.e. on the visible
    surface); it is dynamic if the object mask is > 0 there.
    """
    with torch.no_grad():  # in float64, each Gaussian at the frame nearest its own time
        m64 = subset_model(model, np.ones(len(model), dtype=bool)).double()
        centres = m64.temporal_centres().cpu().numpy()
        times = scene.times
        frame = np.abs(np.clip(centres, times[0], times[-1])[:, None] - times[None]).argmin(axis=1)  # [N]
        own = torch.as_tensor(times[frame], dtype=torch.float64, device=m64.params["means"].device)
        mu = m64.at_time(own).means.cpu().numpy()
    label = np.full(len(mu), -1)  # -1 unclassified, 0 static, 1 dynamic
    for cam_i, gt in gts.items():
        cam = scene.cameras[cam_i]
        xc = mu @ cam.R.T + cam.T
        z = xc[:, 2]
        uv = (xc @ cam.K.T)[:, :2] / np.where(z > 1e-9, z, 1.0)[:, None]
        x, y = np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
        ok = (label < 0) & (z > 1e-9) & (x >= 0) & (x < cam.width) & (y >= 0) & (y < cam.height)
        xs, ys = np.where(ok, x, 0), np.where(ok, y, 0)
        d = gt.depth[frame, ys, xs]
        ok &= np.abs(z - d) <= depth_tol * d
        label[ok] = (gt.objects[frame, ys, xs] > 0)[ok].astype(np.int64)
    long_ = fractions >= split
    short = ~long_
    cl = label >= 0

    def frac(a: np.ndarray, b: np.ndarray) -> float:
        return float(a.sum() / b.sum()) if b.sum() else float("nan")

    return {
        "classified_fraction": float(cl.mean()) if len(cl) else float("nan"),
        "long_lived_on_static": frac(long_ & cl & (label == 0), long_ & cl),
        "short_lived_on_dynamic": frac(short & cl & (label == 1), short & cl),
        "dynamic_that_are_short_lived": frac(short & cl & (label == 1), cl & (label == 1)),
        "static_that_are_long_lived": frac(long_ & cl & (label == 0), cl & (label == 0)),
    }


# --------------------------------------------------------------------------- scores against ground-truth masks


def mask_weights(model: DynamicGaussians, cam: Camera, t: float, masks: np.ndarray, backend: str = "auto"
                 ) -> np.ndarray:
    """Rendered weight each Gaussian carries on each mask at time ``t``: ``[N, M]`` float64.

    ``masks [M, H, W]`` bool. Entry (i, m) is Σ over the pixels of mask m of Gaussian i's
    compositing weight T_i α_i, i.e. the gradient of the mask-summed render of all-ones
    colours with respect to Gaussian i's colour (one render and one backward pass).
    Column sums equal the rendered alpha summed over each mask.
    """
    masks = np.asarray(masks, dtype=bool)
    frozen = subset_model(model, np.ones(model.params["means"].shape[0], dtype=bool))  # no parameter gradients
    dev = frozen.params["means"].device
    ones = torch.ones(frozen.params["means"].shape[0], masks.shape[0], device=dev, requires_grad=True)
    out, _ = render_view(frozen, cam, t, 0, background=None, backend=backend, colors=ones)
    sel = torch.as_tensor(np.moveaxis(masks, 0, -1), dtype=out.image.dtype, device=dev)  # [H, W, M]
    (grad,) = torch.autograd.grad((out.image * sel).sum(), ones)
    return grad.detach().cpu().double().numpy()


def partition_scores(w_dynamic: np.ndarray, w_static: np.ndarray, short: np.ndarray) -> dict[str, float]:
    """Secret 1: how cleanly short-lived Gaussians render the moving content.

    ``w_dynamic [N]`` / ``w_static [N]``: each Gaussian's rendered weight on moving-object
    and on static pixels (``mask_weights``, summed over frames); ``short [N]`` bool. Returns
    the short-lived share of each and their difference ``partition_contrast`` in [-1, 1].
    """
    short = np.asarray(short, dtype=bool)

    def share(w: np.ndarray) -> float:
        total = float(np.sum(w))
        return float(np.sum(w[short]) / total) if total > 0 else float("nan")

    dyn, sta = share(np.asarray(w_dynamic, float)), share(np.asarray(w_static, float))
    return {"short_share_dynamic": dyn, "short_share_static": sta, "partition_contrast": dyn - sta}


def role_switch_score(weights: np.ndarray) -> float:
    """Secret 2: mean total-variation distance between consecutive frames' distributions of
    the weight on the moving objects over Gaussians, ``weights [F, N]`` -> [0, 1].

    0: the same Gaussians, in the same proportions, render the objects in every frame;
    1: every frame uses Gaussians the previous frame did not. Frames without weight are skipped.
    """
    w = np.asarray(weights, dtype=float)
    w = w[w.sum(axis=1) > 0]
    if len(w) < 2:
        return float("nan")
    p = w / w.sum(axis=1, keepdims=True)
    return float((0.5 * np.abs(np.diff(p, axis=0)).sum(axis=1)).mean())
