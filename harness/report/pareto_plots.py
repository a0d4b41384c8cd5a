"""Pareto fronts of a speed-accuracy grid: each method's quality against three costs, per scene.

``pareto_plot(sa, metric, ...)`` draws one row per scene and one column per cost (training
time, render frames per second at one thread, model bytes) for ``sa`` from
``analysis.speed_accuracy_scenes.per_scene(df, metric)``: every cell's mean ± std, coloured by
method and shaped by iteration count, and each method's Pareto front (no other cell of the same
method is at least as good on both axes and better on one) as a dashed step line in its colour.
A cost the runs did not log (render FPS before ``study measure``) leaves its panel saying so.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.ticker import NullFormatter  # noqa: E402

from harness.analysis.aggregate import pareto_mask  # noqa: E402
from harness.report.plots import MAX_WIDTH_IN, save_figure  # noqa: E402
from harness.report.tables import pretty  # noqa: E402
from harness.spec.metrics import LOWER, lookup  # noqa: E402

# column of per_scene, axis label, whether more is better, log axis, scale applied to the values
COSTS = (
    ("train_seconds", "training time (s), one run per core", False, False, 1.0),
    ("render_fps_1thread_mean", "render FPS, 1 thread", True, True, 1.0),
    ("model_bytes_mean", "model size (MB)", False, True, 1e-6),
)
MARKERS = "osD^v"


def front(cost: np.ndarray, quality: np.ndarray, more_cost_better: bool, lower_quality_better: bool) -> np.ndarray:
    """Pareto flags of points whose cost and quality may each be better higher or lower."""
    return pareto_mask(-cost if more_cost_better else cost, -quality if lower_quality_better else quality)


def pareto_plot(sa: pd.DataFrame, metric: str, title: str, path: Path) -> Path:
    """Rows: scenes; columns: ``COSTS``; one colour per method (see the module docstring)."""
    scenes = list(dict.fromkeys(sa.scene))
    methods = list(dict.fromkeys(sa.method))
    its = sorted(sa.iterations.dropna().unique())
    lower = lookup(metric).better == LOWER
    width = min(MAX_WIDTH_IN, 4.2 * len(COSTS))
    fig, axes = plt.subplots(len(scenes), len(COSTS), figsize=(width, 3.1 * len(scenes) + 0.8), squeeze=False,
                             sharey="row", constrained_layout=True)
    for row, scene in zip(axes, scenes):
        cells = sa[(sa.scene == scene) & sa["mean"].notna()]
        for ax, (col, xlabel, more_better, log, scale) in zip(row, COSTS):
            have = cells[cells[col].notna()] if col in cells else cells.iloc[:0]
            if have.empty:
                ax.text(0.5, 0.5, "not measured", transform=ax.transAxes, ha="center", va="center", color="grey")
            for k, m in enumerate(methods):
                sub = have[have.method == m]
                for r in sub.itertuples():
                    ax.errorbar([getattr(r, col) * scale], [r.mean], yerr=[0 if r.std != r.std else r.std],
                                marker=MARKERS[its.index(r.iterations) % len(MARKERS)], color=f"C{k}", ls="none",
                                capsize=2, ms=5)
                if len(sub):
                    x, y = sub[col].to_numpy(float) * scale, sub["mean"].to_numpy(float)
                    on = front(x, y, more_better, lower)
                    order = np.argsort(x[on])
                    ax.step(x[on][order], y[on][order], where="post" if not more_better else "pre",
                            color=f"C{k}", ls="--", lw=1.1)
            if log and len(have) and (have[col] > 0).all():
                ax.set_xscale("log")
                ax.xaxis.set_minor_formatter(NullFormatter())  # decades only: minor labels collide
            ax.set_xlabel(xlabel, fontsize=8)
            ax.grid(alpha=0.3)
        row[0].set_ylabel(pretty(metric), fontsize=8)
        row[0].set_title(str(cells.scene_label.iloc[0]) if len(cells) else scene, loc="left", fontsize=9)
    handles = [Line2D([], [], color=f"C{k}", marker="o", ls="--", label=f"{m or 'all'} (front dashed)")
               for k, m in enumerate(methods)]
    handles += [Line2D([], [], color="grey", marker=MARKERS[k % len(MARKERS)], ls="none",
                       label=f"{int(it):,} iterations") for k, it in enumerate(its)]
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 5), fontsize=8)
    fig.suptitle(title)
    return save_figure(fig, path)
