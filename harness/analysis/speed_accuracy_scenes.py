"""Speed against accuracy per scene: what does each scene need, and is the answer settled?

``aggregate.speed_accuracy`` pools every scene; a budget that is enough for a static
scene may be far too small for fast motion, so a study with several scenes asks per scene:

- ``per_scene``: one row per (scene, variant) that ran on the scene: its method, budget,
  iterations, mean/std/95% CI of the metric, mean train time and #Gaussians, Pareto flags (time
  and Gaussian-count fronts) computed within the scene and method, and the means of the other
  qualities and costs (``EXTRA``: colour-aligned PSNR, LPIPS, render FPS, model bytes, faded
  Gaussians) where the runs logged them;
- ``smallest_per_scene``: per scene and method, the smallest budget whose mean is within
  ``tol_db`` of that method's best on the scene (``aggregate.smallest_within``), and the gap to
  the best with a 95% Welch t-interval, which says whether "within the SESOI" (0.2 dB for PSNR) is statistically settled;
- ``method_comparison``: per scene and grid cell run by two methods, the second method's
  differences in quality (Welch 95% intervals) and ratios of cost against the first.

A variant named ``<method>_b<budget>_i<iterations>`` belongs to ``<method>``
(``method_of``); a plain ``b<budget>_i<iterations>`` grid has one unnamed method.
The report's table and its sentences are ``report.speed_accuracy_text``.

A scene may run a subset of the variants (``StudyScene.variants``) with its own seed count:
a variant with no runs on a scene is absent from that scene's rows. ``study report
speed_accuracy`` uses this module when the study has more than one scene.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd
from scipy import stats

from harness.analysis import aggregate

EXTRA = ("psnr", "psnr_cc", "lpips_alex", "render_fps_1thread", "render_fps_all_cores", "model_bytes", "n_faded")
COLUMNS = ["scene", "scene_label", "method", "variant", "budget", "iterations", "n", "n_failed", "mean", "std", "ci95",
           "train_seconds", "n_gaussians", "pareto_time", "pareto_gaussians", *[f"{m}_mean" for m in EXTRA], "n_alive"]
CHOSEN_CELL = ["scene", "scene_label", "method", "variant", "budget", "iterations", "n", "mean", "ci95",
               "train_seconds", "n_gaussians"]  # copied from the chosen variant's row
CHOSEN_COLUMNS = [*CHOSEN_CELL, "best_variant", "best_mean", "best_ci95", "gap", "gap_ci95", "gap_ci_includes_tol",
                  "largest_budget"]
_GRID = re.compile(r"^(?:(?P<method>.+?)_)?b\d+k?_i\d+k?$")


def method_of(variant: str) -> str:
    """``ftgspp`` for ``ftgspp_b5000_i3000``; "" for a plain ``b5000_i3000`` (or any other name)."""
    m = _GRID.match(str(variant))
    return (m.group("method") or "") if m else ""


def per_scene(df: pd.DataFrame, metric: str = "psnr") -> pd.DataFrame:
    """One row per (scene, variant) with runs on that scene (``COLUMNS``).

    ``n`` counts finished runs, ``n_failed`` the planned runs that did not finish; ``ci95`` is
    the half-width of the t-interval of the mean (NaN when n < 2). Pareto flags compare the
    variants of one scene and method only.
    """
    frames = []
    df = df.assign(method=df.variant.map(method_of))
    for (scene, method), runs in df.groupby(["scene", "method"], sort=False):
        cells = aggregate.speed_accuracy(runs, metric)
        cells["scene"] = scene
        cells["scene_label"] = runs.scene_label.iloc[0]
        cells["method"] = method
        cells["ci95"] = [_ci95(n, std) for n, std in zip(cells["n"], cells["std"])]
        ok = runs[runs.status == "FINISHED"]
        for m in EXTRA:
            means = ok.groupby("variant")[m].mean() if m in ok else pd.Series(dtype=float)
            cells[f"{m}_mean"] = cells.variant.map(means).astype(float)
        cells["n_alive"] = cells["n_gaussians"] - cells["n_faded_mean"]
        frames.append(cells)
    if not frames:
        return pd.DataFrame(columns=COLUMNS)
    return pd.concat(frames, ignore_index=True)[COLUMNS]


def _ci95(n: int, std: float) -> float:
    """Half-width of the 95% t-interval of a mean of ``n`` values with sample std ``std``."""
    if n < 2:
        return math.nan
    return float(stats.t.ppf(0.975, n - 1) * std / math.sqrt(n))


def run_values(df: pd.DataFrame, scene: str, variant: str, metric: str = "psnr") -> np.ndarray:
    """The finished runs' ``metric`` values of one (scene, variant) cell, shape [n_runs]."""
    if metric not in df:
        return np.array([])
    cell = df[(df.scene == scene) & (df.variant == variant) & (df.status == "FINISHED")]
    return cell[metric].dropna().to_numpy(dtype=float)


def welch_ci95(best: np.ndarray, chosen: np.ndarray) -> float:
    """Half-width of the 95% Welch t-interval of mean(best) - mean(chosen) (symmetric about it).

    NaN when either sample has fewer than 2 runs or neither has any spread.
    """
    if len(best) < 2 or len(chosen) < 2 or (best.std() == 0 and chosen.std() == 0):
        return math.nan
    ci = stats.ttest_ind(best, chosen, equal_var=False).confidence_interval(0.95)
    return float(ci.high - ci.low) / 2


def smallest_per_scene(sa: pd.DataFrame, df: pd.DataFrame, tol_db: float | None = None,
                       metric: str = "psnr") -> pd.DataFrame:
    """Per scene and method of ``sa`` (``per_scene``): the smallest budget within ``tol_db`` of
    that method's best on the scene.

    Ties go to fewer iterations, then less time (``aggregate.smallest_within``). ``gap`` is
    best mean - chosen mean (>= 0), ``gap_ci95`` its Welch half-width from the runs in ``df``
    (0 when the chosen variant is the best), ``gap_ci_includes_tol`` whether that interval
    reaches ``tol_db`` (True: "within tol_db" is not settled; NA: no interval),
    ``largest_budget`` the scene's largest budget tried (chosen there: no saturation shown).
    Scenes without a finished run have no row. ``tol_db`` defaults to the metric's smallest
    effect of interest (``aggregate.size_tolerance``).
    """
    tol_db = aggregate.size_tolerance(metric) if tol_db is None else tol_db
    rows = []
    for (scene, _), cells in sa.groupby(["scene", "method"], sort=False):
        chosen = aggregate.smallest_within(cells, tol_db)
        if chosen is None:
            continue
        best = cells.loc[cells["mean"].idxmax()]
        gap = float(best["mean"] - chosen["mean"])
        runs = {v: run_values(df, scene, v, metric) for v in (best.variant, chosen.variant)}
        half = 0.0 if best.variant == chosen.variant else welch_ci95(runs[best.variant], runs[chosen.variant])
        rows.append({**chosen[CHOSEN_CELL].to_dict(),
                     "best_variant": best.variant, "best_mean": best["mean"], "best_ci95": best.ci95,
                     "gap": gap, "gap_ci95": half,
                     "gap_ci_includes_tol": pd.NA if math.isnan(half) else gap - half <= tol_db <= gap + half,
                     "largest_budget": cells["budget"].max()})
    out = pd.DataFrame(rows, columns=CHOSEN_COLUMNS)
    out["gap_ci_includes_tol"] = out["gap_ci_includes_tol"].astype("boolean")
    return out


QUALITY_DIFFS = ("psnr", "psnr_cc", "lpips_alex")  # second method minus first, with a Welch interval
COST_RATIOS = ("train_seconds", "render_fps_1thread", "model_bytes", "n_alive")  # second over first


def method_comparison(df: pd.DataFrame, first: str = "") -> pd.DataFrame:
    """Per (scene, budget, iterations) that two methods ran: the other method against ``first``
    (the study's baseline method; default: the first to appear). ``d_<metric>``: difference of means with its 95% Welch
    interval (``d_<metric>_low``/``_high``) for each of ``QUALITY_DIFFS``; ``r_<cost>``: ratio of
    means for each of ``COST_RATIOS`` (``n_alive``: Gaussians minus those drawn nowhere). Empty
    unless the runs come from exactly two methods."""
    df = df[df.status == "FINISHED"].assign(method=df.variant.map(method_of))
    df = df[df.method != ""]  # variants outside the <method>_b<budget>_i<iterations> grid
    methods = list(dict.fromkeys(df.method))
    if len(methods) != 2 or (first and first not in methods):
        return pd.DataFrame()
    if {"n_gaussians", "n_faded"} <= set(df):
        df = df.assign(n_alive=df.n_gaussians - df.n_faded)
    first = first or methods[0]
    second = next(m for m in methods if m != first)
    rows = []
    for (scene, budget, iterations), cell in df.groupby(["scene", "budget", "iterations"], sort=False):
        a, b = cell[cell.method == first], cell[cell.method == second]
        if a.empty or b.empty:
            continue
        row = {"scene": scene, "scene_label": cell.scene_label.iloc[0], "budget": budget, "iterations": iterations,
               "first": first, "second": second, "n_first": len(a), "n_second": len(b)}
        for m in QUALITY_DIFFS:
            x, y = (a[m].dropna().to_numpy(float), b[m].dropna().to_numpy(float)) if m in cell else ([], [])
            diff = float(np.mean(y) - np.mean(x)) if len(x) and len(y) else math.nan
            low = high = math.nan
            if len(x) > 1 and len(y) > 1 and (x.std() > 0 or y.std() > 0):
                ci = stats.ttest_ind(y, x, equal_var=False).confidence_interval(0.95)
                low, high = float(ci.low), float(ci.high)
            row.update({f"d_{m}": diff, f"d_{m}_low": low, f"d_{m}_high": high})
        for c in COST_RATIOS:
            den = a[c].mean() if c in cell else math.nan
            row[f"r_{c}"] = float(b[c].mean() / den) if c in cell and den and not math.isnan(den) else math.nan
        rows.append(row)
    return pd.DataFrame(rows)
