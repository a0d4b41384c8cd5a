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
- **Stratification** (secret 1: "the histogram has distinct short- and long-lived groups"):
  Hartigan's dip test (the ``diptest`` package) on the lifetimes the histogram draws
  (``lifetime_dip``). Two choices decide what it sees:

  * only Gaussians *drawn somewhere in the clip* count: opacity above θ in at least one of
    its frames (``drawn_in_clip``: sigmoid(o)·φ(t) > θ at some frame time). The histogram
    counts every Gaussian, so the faded ones (Δt = 0, a window wholly outside the clip, or one
    so short it falls between two frames) pile up in its first bin; that spike at 0 is no
    content the model shows, and beside any spread of live lifetimes it alone would make the
    histogram bimodal. (Frames, not the continuous span: a quick FreeTimeGS run on the
    known-size scene had 436 of 1,397 Gaussians above θ only between frames.)
  * lifetimes are capped at the clip length, Δt/T → min(Δt/T, 1). The histogram caps at 2
    (its last bin holds everything longer, ``inf`` included); a cap is needed (``inf`` has
    no rank among finite values) and it sets an atom at the cap. At 1 that atom is a real
    group, "lives at least as long as the clip" (a longer life only reaches further outside
    the frames); at 2 the same Gaussians would split into a spread over [1, 2) and a spike
    at 2, a second mode made by the cap alone.

  The dip D is the largest distance between the empirical CDF and the nearest unimodal
  CDF; ``lifetime_dip_excess`` is D minus the 95th percentile of D for n draws of the
  uniform distribution (the least favourable unimodal null, the package's tables), so it
  is > 0 exactly when the package's p-value is < 0.05, and its size does not shrink with n
  as the p-value does.

    frac = lifetime_fractions(model, theta=0.05, duration=scene.duration)   # [N] Δt/T
    short = subset_model(model, frac < 0.5)
    dip = lifetime_dip(frac, drawn_in_clip(model, 0.05, scene.times))
"""

from __future__ import annotations

import warnings

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


def drawn_in_clip(model: DynamicGaussians, theta: float, times: np.ndarray) -> np.ndarray:
    """``[N]`` bool: the Gaussians whose opacity sigmoid(o)·φ(t) exceeds ``theta`` at one of the
    frame ``times`` (seconds) at least, i.e. that some frame of the clip draws at the lifetime's
    threshold."""
    with torch.no_grad():
        base = model.base_opacity()
        drawn = torch.zeros_like(base, dtype=torch.bool)
        for t in np.asarray(times, dtype=np.float64):
            drawn |= base * model.temporal_opacity(float(t)) > theta
    return drawn.cpu().numpy()


DIP_ALPHA = 0.05  # the excess is measured above the null's (1 - DIP_ALPHA) quantile


def dip_critical_value(n: int, alpha: float = DIP_ALPHA) -> float:
    """The (1 − ``alpha``) quantile of Hartigan's dip for ``n`` uniform draws: the D at which the
    ``diptest`` package's table-interpolated p-value equals ``alpha`` (its own interpolation of
    its null tables, inverted by root finding, so that D > this value ⇔ p < alpha)."""
    from diptest.consts import Consts
    from scipy.optimize import brentq

    with warnings.catch_warnings():  # n beyond the tables: the package uses its largest n (asymptotic)
        warnings.simplefilter("ignore")
        return float(brentq(lambda d: Consts.compute_pval_interpolation(int(n), d) - alpha, 0.0, 1.0, xtol=1e-12))


def lifetime_dip(fractions: np.ndarray, drawn: np.ndarray) -> dict[str, float]:
    """Hartigan's dip test of the drawn Gaussians' Δt/T capped at 1 (module docstring).

    ``fractions [N]`` Δt/T (``inf`` allowed), ``drawn [N]`` bool (``drawn_in_clip``). Returns
    ``dip`` (D), ``p`` (the package's p-value from its tables), ``critical`` (the 95th
    percentile of D under the uniform null at this n), ``excess`` = D − critical and ``n``;
    D, p and the excess are NaN for n ≤ 3, where the test is not defined.
    """
    import diptest

    x = np.minimum(np.asarray(fractions, dtype=np.float64)[np.asarray(drawn, dtype=bool)], 1.0)
    n = int(x.size)
    if n <= 3:
        return {"dip": float("nan"), "p": float("nan"), "critical": float("nan"), "excess": float("nan"), "n": n}
    with warnings.catch_warnings():  # n beyond the tables (72,000): the package's asymptotic p-value
        warnings.simplefilter("ignore")
        dip, p = diptest.diptest(x)
    crit = dip_critical_value(n)
    return {"dip": float(dip), "p": float(p), "critical": crit, "excess": float(dip) - crit, "n": n}


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
