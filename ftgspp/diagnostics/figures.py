"""Matplotlib figures for ``ftgspp.diagnostics.diagnose`` (one function per PNG, Agg backend).

Every figure has a title, labelled axes and a colour bar or legend where colours carry a
value. Each function writes ``path`` and returns it.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from ftgspp.diagnostics.flow_colors import color_wheel, flow_to_rgb  # noqa: E402

DPI = 120


def _save(fig: plt.Figure, path: Path) -> Path:
    path = Path(path)
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def _show(ax: plt.Axes, img: np.ndarray, title: str) -> None:
    ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")


def plot_lifetime_histogram(counts: np.ndarray, edges: np.ndarray, fractions: np.ndarray, split: float,
                            theta: float, duration: float, path: Path) -> Path:
    """Histogram of Δt(θ)/T (log count axis) with the short/long split marked."""
    fig, ax = plt.subplots(figsize=(7, 4))
    widths = np.diff(edges)
    colors = ["tab:orange" if e < split else "tab:blue" for e in edges[:-1]]
    ax.bar(edges[:-1], np.maximum(counts, 0), width=widths, align="edge", color=colors, edgecolor="black",
           linewidth=0.4)  # fmt: skip
    ax.set_yscale("symlog", linthresh=1)
    ax.set_ylim(bottom=0)
    ax.axvline(split, color="red", linestyle="--", linewidth=1.2, label=f"split Δt/T = {split:g}")
    ax.axvline(1.0, color="gray", linestyle=":", linewidth=1.0, label="Δt = T (whole clip)")
    n = len(fractions)
    n0 = int((fractions <= 0).sum())
    n_short = int(((fractions > 0) & (fractions < split)).sum())
    n_long = int((fractions >= split).sum())
    handles, _ = ax.get_legend_handles_labels()
    handles += [Patch(color="tab:orange", label=f"short-lived: {n_short} (+{n0} never above θ, at 0)"),
                Patch(color="tab:blue", label=f"long-lived: {n_long}")]  # fmt: skip
    ax.set_xlabel(f"effective lifetime Δt(θ)/T  (θ = {theta:g}, T = {duration:.3g} s; last bin ≥ {edges[-1]:g})")
    ax.set_ylabel("number of Gaussians (symlog)")
    ax.set_title(f"Effective lifetime of {n} Gaussians")
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def plot_group_renders(gt: np.ndarray, renders: dict[str, np.ndarray], where: str, path: Path) -> Path:
    """Ground truth | full render | short-lived only | long-lived only."""
    panels = {"ground truth": gt, **renders}
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels), 3.4), constrained_layout=True)
    for ax, (name, img) in zip(np.atleast_1d(axes), panels.items()):
        _show(ax, img, name)
    fig.suptitle(f"Renders by lifetime group — {where}")
    return _save(fig, path)


def plot_velocity_map(rgb: np.ndarray, flow: np.ndarray, covered: np.ndarray, where: str, path: Path) -> Path:
    """RGB render | colour-coded image-plane velocity, with a colour-wheel legend and a speed bar."""
    vis, vmax = flow_to_rgb(flow, mask=covered)
    fig = plt.figure(figsize=(11, 4.2), constrained_layout=True)
    gs = fig.add_gridspec(2, 4, width_ratios=[1, 1, 0.05, 0.32], height_ratios=[1, 1])
    ax0, ax1 = fig.add_subplot(gs[:, 0]), fig.add_subplot(gs[:, 1])
    _show(ax0, rgb, "RGB render")
    _show(ax1, vis, "composited velocity (white: alpha ≤ 0.5)")
    cax = fig.add_subplot(gs[:, 2])
    sm = plt.cm.ScalarMappable(cmap="gray", norm=plt.Normalize(0, vmax))
    fig.colorbar(sm, cax=cax, label="speed (px/frame) = HSV value")
    wax = fig.add_subplot(gs[0, 3])
    wax.imshow(color_wheel(), extent=(-vmax, vmax, vmax, -vmax))
    wax.set_title("direction (hue)", fontsize=9)
    wax.set_xlabel("dx (px/frame)", fontsize=8)
    wax.set_ylabel("dy (down)", fontsize=8)
    wax.tick_params(labelsize=7)
    fig.suptitle(f"Velocity map — {where}")
    return _save(fig, path)


def plot_xt_slice(gt: np.ndarray, render: np.ndarray, cam: str, row: int, fps: float, path: Path,
                  gt_name: str = "ground truth") -> Path:
    """Ground truth | render | |difference| of one image row over time (time goes down);
    ``gt_name`` says which ground truth (e.g. the noise-free frames)."""
    n_frames, width = gt.shape[:2]
    ext = (-0.5, width - 0.5, n_frames - 0.5, -0.5)
    diff = np.abs(gt - render).mean(axis=-1)
    height = float(np.clip(4.3 * n_frames / width, 2.5, 8.0)) + 1.0  # frames stretched to stay readable
    fig, axes = plt.subplots(1, 3, figsize=(13, height), constrained_layout=True)
    for ax, img, name in ((axes[0], gt, gt_name), (axes[1], render, "render")):
        ax.imshow(np.clip(img, 0, 1), extent=ext, aspect="auto", interpolation="nearest")
        ax.set_title(name, fontsize=9)
    im = axes[2].imshow(diff, extent=ext, aspect="auto", cmap="magma", vmin=0, interpolation="nearest")
    axes[2].set_title(f"|{gt_name} − render| (mean over RGB)", fontsize=9)
    fig.colorbar(im, ax=axes[2], label="absolute error")
    for ax in axes:
        ax.set_xlabel("x (px)")
        ax.set_ylabel(f"frame ({fps:g} fps), time ↓")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    fig.suptitle(f"x–t slice: row y = {row} of {cam} over {n_frames} frames")
    return _save(fig, path)


def plot_motion_error(velocity: np.ndarray, covered: np.ndarray, gt_flow: np.ndarray, objects: np.ndarray,
                      numbers: dict, where: str, path: Path) -> Path:
    """Rendered speed | ground-truth speed | end-point error, on one colour scale (units/s)."""
    speed = np.where(covered, np.linalg.norm(velocity, axis=-1), np.nan)
    gt_speed = np.linalg.norm(gt_flow, axis=-1)
    epe = np.where(covered, np.linalg.norm(velocity - gt_flow, axis=-1), np.nan)
    # scale from the ground truth (2x its top speed) so a large leak saturates instead of hiding it
    moving = gt_speed[objects > 0]
    ref = moving if moving.size else speed[np.isfinite(speed)]
    vmax = max(2.0 * float(np.percentile(ref, 99)) if ref.size else 1.0, 1e-6)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), constrained_layout=True)
    cmap = plt.get_cmap("viridis").with_extremes(bad="white")
    panels = (("composited speed |v| (white: alpha ≤ 0.5)", speed), ("ground-truth speed |v_gt|", gt_speed),
              ("end-point error |v − v_gt|", epe))  # fmt: skip
    for ax, (name, img) in zip(axes, panels):
        im = ax.imshow(img, cmap=cmap, vmin=0, vmax=vmax, interpolation="nearest")
        ax.contour(objects > 0, levels=[0.5], colors="red", linewidths=0.6)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("x (px)")
        ax.set_ylabel("y (px)")
    fig.colorbar(im, ax=axes, label="world units / s", shrink=0.9, extend="max")
    fig.suptitle(
        f"Motion error — {where}; red: moving objects. All frames: EPE on objects "
        f"{numbers['epe_dynamic']:.3f}, speed leaking into static {numbers['leak_static']:.3f} "
        f"(mean GT object speed {numbers['gt_speed_dynamic']:.3f})", fontsize=10)
    return _save(fig, path)
