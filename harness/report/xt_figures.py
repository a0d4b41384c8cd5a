"""Haze in x–t slices (secret 4): one figure per scene of a study whose file lists ``xt_grid``.

Every training run keeps the arrays of its x–t slice (one image row of the held-out camera over
all frames) in its ``diagnostics/xt_slice.npz`` artifact (``ftgspp/diagnostics/diagnose.py``
``save_xt_arrays``): the render's slice and the ground truth's, recorded and, on synthetic
scenes, noise-free. ``xt_grid_figure`` draws, for one scene, a row per variant and a column per
seed (the first ``MAX_SEEDS`` finished seeds), each panel |render − noise-free ground truth|
(mean over RGB) with time going down, all on one colour scale with one colour bar, and a
ground-truth row: the noise-free slice itself and |recorded − noise-free| (the sensor noise
and codec the video carries) on the same scale. Haze — a background that drifts where the
scene is still — shows as texture in the static columns of a variant's row; what every
variant shares, at every seed, is the method's, not the relocation rule's.

``figures(data, out)`` writes ``xt_grid_<scene>.png`` for each scene and returns the
(caption, path) pairs the report page links (``report.writer``). Runs whose slice arrays cannot
be read (older runs, a committed report without a store) are left blank in their panel.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from harness.report import committed, plots  # noqa: E402  (plots.save_figure: the report's one way to write a figure)
from harness.report.results import ReportData  # noqa: E402

ARTIFACT = "diagnostics/xt_slice.npz"
MAX_SEEDS = 5  # columns: the first finished seeds, up to this many
PANEL_W_IN = 2.6


def xt_difference(arrays: dict[str, np.ndarray]) -> np.ndarray:
    """|render − noise-free ground truth|, mean over RGB, ``[F, W]`` (the recorded ground truth
    where the scene has no noise-free frames)."""
    ref = arrays.get("gt_clean", arrays["gt"]).astype(np.float32) / 255.0
    return np.abs(arrays["render"].astype(np.float32) - ref).mean(axis=-1)


def xt_grid_figure(rows: dict[str, dict[int, np.ndarray | None]], truth: dict[str, np.ndarray] | None, title: str,
                   path: Path) -> Path:
    """The grid of one scene: ``rows`` maps variant -> {seed: |difference| ``[F, W]`` or None}
    (every row has the same seeds, in column order); ``truth``: one run's slice arrays (``gt``
    and, where present, ``gt_clean``) for the ground-truth row, or None to leave it out. One
    colour scale for every difference panel: 0 to the 99th percentile of them all."""
    seeds = list(next(iter(rows.values())))
    diffs = [d for by_seed in rows.values() for d in by_seed.values() if d is not None]
    if truth is not None and "gt_clean" in truth:
        noise = np.abs(truth["gt"].astype(np.float32) - truth["gt_clean"].astype(np.float32)).mean(axis=-1) / 255.0
        diffs.append(noise)
    else:
        noise = None
    pooled = np.concatenate([d.ravel() for d in diffs]) if diffs else np.zeros(1)
    vmax = max(float(np.percentile(pooled, 99)), 1e-4)
    shape = diffs[0].shape if diffs else (1, 1)
    panel_h = float(np.clip(PANEL_W_IN * shape[0] / max(shape[1], 1), 1.0, 4.0))
    n_rows = len(rows) + (truth is not None)
    n_cols = max(len(seeds), 2 if truth is not None else 1)
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(min(plots.MAX_WIDTH_IN, PANEL_W_IN * n_cols + 1.2),
                                                      panel_h * n_rows + 0.9),
                             squeeze=False, constrained_layout=True)
    image = None
    extent = (-0.5, shape[1] - 0.5, shape[0] - 0.5, -0.5)

    def show(ax: plt.Axes, d: np.ndarray | None) -> None:
        nonlocal image
        if d is None:
            ax.text(0.5, 0.5, "no slice arrays", ha="center", va="center", fontsize=8, transform=ax.transAxes)
            return
        image = ax.imshow(d, extent=extent, aspect="auto", cmap="magma", vmin=0.0, vmax=vmax, interpolation="nearest")

    for r, (variant, by_seed) in enumerate(rows.items()):
        for c, seed in enumerate(seeds):
            show(axes[r, c], by_seed[seed])
            if r == 0:
                axes[r, c].set_title(f"seed {seed}", fontsize=9)
        # the variant's name across, beside its row (long names do not fit along a panel's height)
        axes[r, 0].set_ylabel(variant, fontsize=8, rotation=0, ha="right", va="center")
        for ax in axes[r, len(seeds):]:
            ax.set_visible(False)
    if truth is not None:
        r = len(rows)
        ref = truth.get("gt_clean", truth["gt"])
        axes[r, 0].imshow(ref, extent=extent, aspect="auto", interpolation="nearest")
        axes[r, 0].set_title("noise-free ground truth" if "gt_clean" in truth else "ground truth", fontsize=9)
        axes[r, 0].set_ylabel("ground truth", fontsize=8, rotation=0, ha="right", va="center")
        if noise is not None:
            show(axes[r, 1], noise)
            axes[r, 1].set_title("|recorded − noise-free|", fontsize=9)
        for ax in axes[r, 1 + (noise is not None):]:
            ax.set_visible(False)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    for ax in axes[-1, :]:
        ax.set_xlabel("x (px)", fontsize=8)
    if image is not None:
        fig.colorbar(image, ax=axes, shrink=0.6, extend="max",
                     label="|render − noise-free ground truth|, mean over RGB")
    fig.suptitle(f"{title} (time runs down each panel)")
    return plots.save_figure(fig, path)


def read_slices(store: object, run_id: str) -> dict[str, np.ndarray] | None:
    """The run's ``xt_slice.npz`` arrays, or None when it has none (or the store cannot give them)."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            (copy,) = store.copy_artifacts(run_id, [ARTIFACT], Path(tmp), under="diagnostics")
            with np.load(copy) as z:
                return {k: z[k] for k in z.files}
        except Exception:  # no such artifact (a run older than the arrays), or an unreadable store
            return None


def figures(data: ReportData, out: Path) -> list[tuple[str, Path]]:
    """``xt_grid_<scene>.png`` per scene when the study lists the ``xt_grid`` plot; (caption, path)
    pairs. Without a tracking store (a report from committed runs has no arrays) the figures already in
    ``out`` for those scenes, drawn by the report the runs came from."""
    if "xt_grid" not in data.study.plots:
        return []
    variants, scenes = data.order()
    labels = data.labels()
    if data.store is None:  # a report from committed runs: the figures its runs' report drew, if there
        return [(_caption(labels.get(s, s)), out / f"xt_grid_{s}.png") for s in scenes
                if (out / f"xt_grid_{s}.png").is_file()]
    made = []
    ok = data.df[data.df.status == "FINISHED"]
    filled = committed.filled_rows(data)
    for scene in scenes:
        here = ok[ok.scene == scene]
        if "instance" in here and (here.instance > 0).any():
            continue  # a fresh instance (one run): the slices show the scenes as written
        if len(here) and filled[here.index].all():  # its runs come from the committed report: its figure
            name = f"xt_grid_{scene}.png"
            source, target = data.filled.folder / name, out / name
            if source.is_file():
                if source.resolve() != target.resolve():
                    shutil.copyfile(source, target)
                made.append((_caption(labels.get(scene, scene)), target))
            continue
        seeds = sorted({int(s) for s in here.seed})[:MAX_SEEDS]
        shown = [v for v in variants if (here.variant == v).any()]
        if not seeds or not shown:
            continue
        rows: dict[str, dict[int, np.ndarray | None]] = {}
        truth = None
        for v in shown:
            rows[v] = {}
            for seed in seeds:
                run = here[(here.variant == v) & (here.seed == seed)]
                arrays = read_slices(data.store, str(run.run_id.iloc[0])) if len(run) else None
                rows[v][seed] = None if arrays is None else xt_difference(arrays)
                truth = truth or arrays
        if truth is None:
            continue
        path = xt_grid_figure(rows, truth, f"{data.study.name}: x–t slices, {labels.get(scene, scene)}",
                              out / f"xt_grid_{scene}.png")
        made.append((_caption(labels.get(scene, scene)), path))
    return made


def _caption(label: str) -> str:
    return (f"x–t slices of |render − noise-free ground truth| on {label}: a row per variant, a column per seed,"
            " one colour scale")
