"""The report's figures (matplotlib, Agg backend): strip, speed-accuracy, stability.

- ``strip_plot``: every run's metric per variant, one panel per scene, mean +- std bars,
  failed runs counted under each variant (the paper's run-to-run figure);
- ``speed_accuracy_plot``: PSNR against training time and against #Gaussians, Pareto
  front joined, the smallest budget within the SESOI (0.2 dB) of the best starred;
  ``speed_accuracy_scenes_plot``: the same, one row per scene (``analysis.speed_accuracy_scenes``);
- ``stability_plot``: per difficulty cell and method, mean +- std, spread and failure rate.

The x–t haze grids (``xt_grid``) are ``report.xt_figures``; they write through ``save_figure``.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from harness.report.tables import pretty  # noqa: E402

DPI = 120  # every report figure's resolution (harness/report/figure_checks.py measures widths at it)


def save_figure(fig: plt.Figure, path: Path) -> Path:
    """Write ``fig`` to ``path`` (parents created, 120 dpi, tight) and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return path


# A report figure is at most ~2,000 px wide at 120 dpi (harness/report/figure_checks.py): panels
# wrap onto further rows rather than widen the figure.
MAX_WIDTH_IN = 15.5


def panel_grid(n: int, panel_w: float, panel_h: float, **kw) -> tuple[plt.Figure, list[plt.Axes]]:
    """``n`` panels of about ``panel_w`` x ``panel_h`` inches, wrapped into rows no wider than
    ``MAX_WIDTH_IN``; the unused cells of the last row are hidden. Returns the figure and the
    ``n`` axes in reading order."""
    cols = max(1, min(n, int(MAX_WIDTH_IN // panel_w)))
    rows = -(-n // cols)
    width = min(MAX_WIDTH_IN, panel_w * cols)
    fig, axes = plt.subplots(rows, cols, figsize=(width, panel_h * rows), squeeze=False, constrained_layout=True, **kw)
    flat = list(axes.flat)
    for ax in flat[n:]:
        ax.set_visible(False)
    return fig, flat[:n]


def strip_plot(df: pd.DataFrame, metric: str, variants: list[str], scenes: list[str],
               labels: dict[str, str], title: str, path: Path) -> Path:
    """Per-run values of ``metric`` per variant, one panel per scene holding the variants run
    there (a variant keeps its colour in every panel), panels wrapped into rows."""
    present = {s: [v for v in variants if ((df.variant == v) & (df.scene == s)).any()] or variants for s in scenes}
    widest = max(len(vs) for vs in present.values())
    fig, axes = panel_grid(len(scenes), max(3.2, 0.9 * widest + 1.4), 4.2, sharey=True)
    rng = np.random.default_rng(0)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, scene in zip(axes, scenes):
        ticks = []
        shown = present[scene]
        for i, v in enumerate(shown):
            sub = df[(df.variant == v) & (df.scene == scene)]
            ok = sub[sub.status == "FINISHED"]
            vals = ok[metric].dropna().to_numpy(dtype=float) if metric in ok else np.array([])
            color = colors[variants.index(v) % len(colors)]
            if len(vals):
                x = i + rng.uniform(-0.12, 0.12, len(vals))
                ax.scatter(x, vals, s=22, color=color, alpha=0.8, zorder=3, label="run" if i == 0 else None)
                std = vals.std(ddof=1) if len(vals) > 1 else 0.0
                ax.errorbar(i + 0.3, vals.mean(), yerr=std, fmt="_", color="black", capsize=4, markersize=12,
                            zorder=4, label="mean ± std" if i == 0 else None)
            n_bad = int((sub.status != "FINISHED").sum())
            ticks.append(v + (f"\n({n_bad} failed)" if n_bad else ""))
        # a few names slanted; many upright, where slanted boxes would overlap their neighbours
        rotation = 0 if len(shown) <= 2 else 30 if len(shown) <= 6 else 90
        ax.set_xticks(range(len(shown)), ticks, rotation=rotation, ha="right" if rotation == 30 else "center",
                      fontsize=8)
        ax.set_title(labels.get(scene, scene), fontsize=10)
        ax.grid(axis="y", alpha=0.3)
        ax.set_xlim(-0.6, len(shown) - 0.4)
        ax.yaxis.set_tick_params(labelleft=True)
    axes[0].set_ylabel(pretty(metric))
    handles, names = axes[0].get_legend_handles_labels()
    if handles:
        axes[0].legend(handles, names, loc="best", fontsize=8)
    fig.suptitle(title)
    return save_figure(fig, path)


def speed_accuracy_plot(sa: pd.DataFrame, chosen: pd.Series | None, title: str, path: Path) -> Path:
    """PSNR vs train time and vs #Gaussians with the Pareto fronts; ``chosen`` starred."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True, constrained_layout=True)
    _speed_accuracy_row(axes, sa, chosen)
    axes[0].set_title("PSNR vs training time")
    axes[1].set_title("PSNR vs number of Gaussians")
    fig.suptitle(title)
    return save_figure(fig, path)


def speed_accuracy_scenes_plot(sa: pd.DataFrame, chosen: pd.DataFrame, title: str, path: Path) -> Path:
    """``speed_accuracy_plot`` with one row per scene of ``sa`` (``analysis.speed_accuracy_scenes.per_scene``);
    each scene's Pareto fronts are its own, its row of ``chosen`` (``smallest_per_scene``) starred."""
    scenes = list(dict.fromkeys(sa.scene))
    fig, axes = plt.subplots(len(scenes), 2, figsize=(11, 4.0 * len(scenes)), sharey="row", squeeze=False,
                             constrained_layout=True)
    for row, scene in zip(axes, scenes):
        cells = sa[sa.scene == scene]
        pick = chosen[chosen.scene == scene]
        _speed_accuracy_row(row, cells, pick.iloc[0] if len(pick) else None)
        label = cells.scene_label.iloc[0]
        row[0].set_title(label, loc="left", fontsize=10)  # the x axes say which cost each panel shows
    fig.suptitle(title)
    return save_figure(fig, path)


def _speed_accuracy_row(axes: np.ndarray, sa: pd.DataFrame, chosen: pd.Series | None) -> None:
    """Draw ``sa`` on two axes: PSNR vs train time, PSNR vs #Gaussians (log x); mean +- std per
    variant, coloured by budget and shaped by iteration count (a legend, no labels on the points,
    so none can overlap), Pareto front dashed, ``chosen`` starred."""
    ok = sa[sa["mean"].notna()]
    budgets = sorted(ok.budget.unique()) if "budget" in ok else []
    its = sorted(ok.iterations.unique())
    markers = "os^Dv"
    for ax, xcol, front, xlabel in (
        (axes[0], "train_seconds", "pareto_time", "training time (s)"),
        (axes[1], "n_gaussians", "pareto_gaussians", "number of Gaussians"),
    ):
        for r in ok.itertuples():
            colour = f"C{budgets.index(r.budget) % 10}" if budgets else "C0"
            ax.errorbar([getattr(r, xcol)], [r.mean], yerr=[0 if r.std != r.std else r.std], capsize=3,
                        marker=markers[its.index(r.iterations) % len(markers)], color=colour, ls="none")
        pf = ok[ok[front]].sort_values(xcol)
        if len(pf):
            ax.step(pf[xcol], pf["mean"], where="post", color="black", lw=1.2, ls="--")
        if chosen is not None:
            ax.scatter([chosen[xcol]], [chosen["mean"]], marker="*", s=260, color="gold", edgecolor="black", zorder=5)
        if xcol == "n_gaussians" and len(ok) and ok[xcol].min() > 0:
            ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(pretty("psnr"))
    line = plt.Line2D
    handles = [line([], [], color=f"C{k % 10}", marker="o", ls="none", label=f"budget {b:,.0f}")
               for k, b in enumerate(budgets)]
    handles += [line([], [], color="grey", marker=markers[k % len(markers)], ls="none", label=f"{int(it):,} iterations")
                for k, it in enumerate(its)]
    handles += [line([], [], color="black", ls="--", label="Pareto front")]
    if chosen is not None:
        handles += [line([], [], marker="*", ms=14, color="gold", mec="black", ls="none",
                         label=f"smallest budget within the SESOI: {chosen['variant']}")]
    axes[1].legend(handles=handles, fontsize=7, loc="center left", bbox_to_anchor=(1.02, 0.5))


def stability_plot(st: pd.DataFrame, variants: list[str], scenes: list[str], labels: dict[str, str],
                   title: str, path: Path) -> Path:
    """Three panels, one above the other, over difficulty cells: mean +- std PSNR, spread,
    failure rate (each non-zero rate labelled, turned upright so neighbours cannot collide)."""
    width = min(MAX_WIDTH_IN, max(8.0, 1.0 * len(scenes) + 2.5))
    fig, axes = plt.subplots(3, 1, figsize=(width, 11.0), sharex=True, constrained_layout=True)
    x = np.arange(len(scenes))
    bar = 0.8 / max(1, len(variants))
    for k, v in enumerate(variants):
        sub = st[st.variant == v].set_index("scene").reindex(scenes)
        offs = x - 0.4 + bar * (k + 0.5)
        axes[0].errorbar(offs, sub["mean"], yerr=sub["std"].fillna(0), fmt="o", capsize=4, label=v, color=f"C{k}")
        axes[1].bar(offs, sub["spread"].fillna(0), bar, label=v, color=f"C{k}")
        rate = sub["failure_rate"]
        bars = axes[2].bar(offs, rate.fillna(0) * 100, bar, label=v, color=f"C{k}")
        axes[2].bar_label(bars, labels=[f"{r:.0%}" if r == r and r > 0 else "" for r in rate], fontsize=7,
                          rotation=90, padding=2)
    names = [labels.get(s, s) for s in scenes]
    for ax, ylabel, sub_title in (
        (axes[0], pretty(st.attrs.get("metric", "psnr")) + " (mean ± std)", "quality"),
        (axes[1], f"spread: max − min {pretty(st.attrs.get('metric', 'psnr')).removesuffix(' (dB)')} (dB)",
         "run-to-run spread"),
        (axes[2], "breaking runs (%)" if "quality_rate" in st else "failed runs (%)",
         "labelled where above 0 %: runs that crashed or diverged"
         + (", or collapsed their colours (ladders.png; quality losses there)" if "quality_rate" in st else "")),
    ):
        ax.set_xlim(-0.6, len(scenes) - 0.4)
        ax.set_ylabel(ylabel)
        ax.set_title(sub_title, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    axes[2].set_xticks(x, names, rotation=90)  # upright names: a box per name, none can overlap
    axes[2].set_xlabel("difficulty cell")
    axes[2].set_ylim(0, 125)
    handles, names = axes[0].get_legend_handles_labels()  # outside the panels: no point hides under it
    fig.legend(handles, names, title="method", fontsize=8, ncols=min(len(variants), 5), loc="outside lower center")
    fig.suptitle(title)
    return save_figure(fig, path)
