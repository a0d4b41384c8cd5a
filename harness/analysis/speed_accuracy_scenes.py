"""Speed against accuracy per scene: what does each scene need, and is the answer settled?

``aggregate.speed_accuracy`` pools every scene; a budget that is enough for a static
scene may be far too small for fast motion, so a study with several scenes asks per scene:

- ``per_scene``: one row per (scene, variant) that ran on the scene: budget, iterations,
  mean/std/95% CI of the metric, mean train time and #Gaussians, Pareto flags (time and
  Gaussian-count fronts) computed within the scene;
- ``smallest_per_scene``: per scene, the smallest budget whose mean is within ``tol_db`` of
  the scene's best (``aggregate.smallest_within``), and the gap to the best with a 95% Welch
  t-interval, which says whether "within 0.1 dB" is statistically settled;
The report's table and its sentences are ``report.speed_accuracy_text``.

A scene may run a subset of the variants (``StudyScene.variants``) with its own seed count:
a variant with no runs on a scene is absent from that scene's rows. ``study report
speed_accuracy`` uses this module when the study has more than one scene.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from scipy import stats

from harness.analysis import aggregate

COLUMNS = ["scene", "scene_label", "variant", "budget", "iterations", "n", "n_failed", "mean", "std", "ci95",
           "train_seconds", "n_gaussians", "pareto_time", "pareto_gaussians"]
CHOSEN_CELL = ["scene", "scene_label", "variant", "budget", "iterations", "n", "mean", "ci95",
               "train_seconds", "n_gaussians"]  # copied from the chosen variant's row
CHOSEN_COLUMNS = [*CHOSEN_CELL, "best_variant", "best_mean", "best_ci95", "gap", "gap_ci95", "gap_ci_includes_tol",
                  "largest_budget"]


def per_scene(df: pd.DataFrame, metric: str = "psnr") -> pd.DataFrame:
    """One row per (scene, variant) with runs on that scene (``COLUMNS``).

    ``n`` counts finished runs, ``n_failed`` the planned runs that did not finish; ``ci95`` is
    the half-width of the t-interval of the mean (NaN when n < 2). Pareto flags compare the
    variants of one scene only.
    """
    frames = []
    for scene, runs in df.groupby("scene", sort=False):
        cells = aggregate.speed_accuracy(runs, metric)
        cells["scene"] = scene
        cells["scene_label"] = runs.scene_label.iloc[0]
        cells["ci95"] = [_ci95(n, std) for n, std in zip(cells["n"], cells["std"])]
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


def smallest_per_scene(sa: pd.DataFrame, df: pd.DataFrame, tol_db: float = 0.1,
                       metric: str = "psnr") -> pd.DataFrame:
    """Per scene of ``sa`` (``per_scene``): the smallest budget within ``tol_db`` of the best.

    Ties go to fewer iterations, then less time (``aggregate.smallest_within``). ``gap`` is
    best mean - chosen mean (>= 0), ``gap_ci95`` its Welch half-width from the runs in ``df``
    (0 when the chosen variant is the best), ``gap_ci_includes_tol`` whether that interval
    reaches ``tol_db`` (True: "within tol_db" is not settled; NA: no interval),
    ``largest_budget`` the scene's largest budget tried (chosen there: no saturation shown).
    Scenes without a finished run have no row.
    """
    rows = []
    for scene, cells in sa.groupby("scene", sort=False):
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
