"""The report's figures (matplotlib, Agg backend): strip, speed-accuracy, stability.

- ``strip_plot``: every run's metric per variant, one panel per scene, mean +- std bars,
  failed runs counted under each variant (the paper's run-to-run figure);
- ``speed_accuracy_plot``: PSNR against training time and against #Gaussians, Pareto
  front joined, the smallest budget within 0.1 dB of the best starred;
  ``speed_accuracy_scenes_plot``: the same, one row per scene (``analysis.speed_accuracy_scenes``);
- ``stability_plot``: per difficulty cell and method, mean +- std, spread and failure rate.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from harness.report.tables import pretty  # noqa: E402


def save_figure(fig: plt.Figure, path: Path) -> Path:
    """Write ``fig`` to ``path`` (parents created, 120 dpi, tight) and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def strip_plot(df: pd.DataFrame, metric: str, variants: list[str], scenes: list[str],
               labels: dict[str, str], title: str, path: Path) -> Path:
    """Per-run values of ``metric`` per variant, one panel per scene."""
    fig, axes = plt.subplots(1, len(scenes), figsize=(max(4.0, 1.1 * len(variants) + 1.5) * len(scenes), 4.2),
                             squeeze=False, sharey=True, constrained_layout=True)
    rng = np.random.default_rng(0)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, scene in zip(axes[0], scenes):
        ticks = []
        for i, v in enumerate(variants):
            sub = df[(df.variant == v) & (df.scene == scene)]
            ok = sub[sub.status == "FINISHED"]
            vals = ok[metric].dropna().to_numpy(dtype=float) if metric in ok else np.array([])
            color = colors[i % len(colors)]
            if len(vals):
                x = i + rng.uniform(-0.12, 0.12, len(vals))
                ax.scatter(x, vals, s=22, color=color, alpha=0.8, zorder=3, label="run" if i == 0 else None)
                std = vals.std(ddof=1) if len(vals) > 1 else 0.0
                ax.errorbar(i + 0.3, vals.mean(), yerr=std, fmt="_", color="black", capsize=4, markersize=12,
                            zorder=4, label="mean ± std" if i == 0 else None)
            n_bad = int((sub.status != "FINISHED").sum())
            ticks.append(v + (f"\n({n_bad} failed)" if n_bad else ""))
        ax.set_xticks(range(len(variants)), ticks, rotation=20 if len(variants) > 3 else 0, ha="center")
        ax.set_title(labels.get(scene, scene))
        ax.set_xlabel("variant")
        ax.grid(axis="y", alpha=0.3)
        ax.set_xlim(-0.6, len(variants) - 0.4)
    axes[0][0].set_ylabel(pretty(metric))
    handles, names = axes[0][0].get_legend_handles_labels()
    if handles:
        axes[0][0].legend(handles, names, loc="best", fontsize=8)
    fig.suptitle(title)
    return save_figure(fig, path)


def speed_accuracy_plot(sa: pd.DataFrame, chosen: pd.Series | None, title: str, path: Path) -> Path:
    """PSNR vs train time and vs #Gaussians with the Pareto fronts; ``chosen`` starred."""
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True, constrained_layout=True)
    _speed_accuracy_row(axes, sa, chosen)
    axes[0].set_title("PSNR vs training time")
    axes[1].set_title("PSNR vs number of Gaussians")
    axes[1].legend(loc="lower right", fontsize=8)
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
        row[0].set_title(f"{label}: PSNR vs training time")
        row[1].set_title(f"{label}: PSNR vs number of Gaussians")
        row[1].legend(loc="best", fontsize=8)
    fig.suptitle(title)
    return save_figure(fig, path)


def _speed_accuracy_row(axes: np.ndarray, sa: pd.DataFrame, chosen: pd.Series | None) -> None:
    """Draw ``sa`` on two axes: PSNR vs train time, PSNR vs #Gaussians (log x); mean +- std per
    variant coloured by iterations, Pareto front dashed, ``chosen`` starred."""
    ok = sa[sa["mean"].notna()]
    for ax, xcol, front, xlabel in (
        (axes[0], "train_seconds", "pareto_time", "training time (s)"),
        (axes[1], "n_gaussians", "pareto_gaussians", "number of Gaussians"),
    ):
        its = sorted(ok.iterations.unique())
        for k, it in enumerate(its):
            sub = ok[ok.iterations == it]
            ax.errorbar(sub[xcol], sub["mean"], yerr=sub["std"].fillna(0), fmt="o", capsize=3,
                        label=f"{int(it)} iterations", color=f"C{k}")
        for r in ok.itertuples():
            ax.annotate(r.variant, (getattr(r, xcol), r.mean), textcoords="offset points", xytext=(4, 4), fontsize=7)
        pf = ok[ok[front]].sort_values(xcol)
        if len(pf):
            ax.step(pf[xcol], pf["mean"], where="post", color="black", lw=1.2, ls="--", label="Pareto front")
        if chosen is not None:
            ax.scatter([chosen[xcol]], [chosen["mean"]], marker="*", s=260, color="gold", edgecolor="black", zorder=5,
                       label=f"smallest budget within 0.1 dB: {chosen['variant']}")
        if xcol == "n_gaussians" and len(ok) and ok[xcol].min() > 0:
            ax.set_xscale("log")
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(pretty("psnr"))


def stability_plot(st: pd.DataFrame, variants: list[str], scenes: list[str], labels: dict[str, str],
                   title: str, path: Path) -> Path:
    """Three panels over difficulty cells: mean +- std PSNR, spread, failure rate."""
    fig, axes = plt.subplots(1, 3, figsize=(max(12.0, 3.5 * len(scenes)), 4.6), constrained_layout=True)
    x = np.arange(len(scenes))
    width = 0.8 / max(1, len(variants))
    for k, v in enumerate(variants):
        sub = st[st.variant == v].set_index("scene").reindex(scenes)
        offs = x - 0.4 + width * (k + 0.5)
        axes[0].errorbar(offs, sub["mean"], yerr=sub["std"].fillna(0), fmt="o", capsize=4, label=v, color=f"C{k}")
        axes[1].bar(offs, sub["spread"].fillna(0), width, label=v, color=f"C{k}")
        bars = axes[2].bar(offs, sub["failure_rate"].fillna(0) * 100, width, label=v, color=f"C{k}")
        axes[2].bar_label(bars, labels=[f"{r:.0%}" if r == r else "n/a" for r in sub["failure_rate"]], fontsize=7)
    names = [labels.get(s, s) for s in scenes]
    for ax, ylabel, sub_title in (
        (axes[0], pretty("psnr") + " (mean ± std)", "quality"),
        (axes[1], "spread: max − min PSNR (dB)", "run-to-run spread"),
        (axes[2], "failed or diverged runs (%)", "failure rate"),
    ):
        ax.set_xticks(x, names, rotation=20, ha="right")
        ax.set_xlim(-0.6, len(scenes) - 0.4)
        ax.set_xlabel("difficulty cell")
        ax.set_ylabel(ylabel)
        ax.set_title(sub_title)
        ax.grid(axis="y", alpha=0.3)
    axes[2].set_ylim(0, 105)
    axes[0].legend(title="method", fontsize=8)
    fig.suptitle(title)
    return save_figure(fig, path)
