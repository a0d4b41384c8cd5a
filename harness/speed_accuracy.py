"""Speed against accuracy per scene: what does each scene need, and is the answer settled?

``aggregate.speed_accuracy`` pools every scene; a budget that is enough for a static
scene may be far too small for fast motion, so a study with several scenes asks per scene:

- ``per_scene``: one row per (scene, variant) that ran on the scene: budget, iterations,
  mean/std/95% CI of the metric, mean train time and #Gaussians, Pareto flags (time and
  Gaussian-count fronts) computed within the scene;
- ``smallest_per_scene``: per scene, the smallest budget whose mean is within ``tol_db`` of
  the scene's best (``aggregate.smallest_within``), and the gap to the best with a 95% Welch
  t-interval, which says whether "within 0.1 dB" is statistically settled;
- ``markdown`` / ``report_markdown``: the report's table and one sentence per scene pair.

A scene may run a subset of the variants (``SceneSpec.variants``) with its own seed count:
a variant with no runs on a scene is absent from that scene's rows. ``study report
speed_accuracy`` uses this module when the study has more than one scene.
"""

from __future__ import annotations

import math
from itertools import combinations

import numpy as np
import pandas as pd
from scipy import stats

from harness import aggregate
from harness.tables import PRETTY

COLUMNS = ["scene", "scene_label", "variant", "budget", "iterations", "n", "n_failed", "mean", "std", "ci95",
           "train_seconds", "n_gaussians", "pareto_time", "pareto_gaussians"]
CHOSEN_CELL = ["scene", "scene_label", "variant", "budget", "iterations", "n", "mean", "ci95",
               "train_seconds", "n_gaussians"]  # copied from the chosen variant's row
CHOSEN_COLUMNS = [*CHOSEN_CELL, "best_variant", "best_mean", "best_ci95", "gap", "gap_ci95", "gap_ci_includes_tol"]


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
    reaches ``tol_db`` (True: "within tol_db" is not settled; NA: no interval). Scenes without
    a finished run have no row.
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
                     "gap_ci_includes_tol": pd.NA if math.isnan(half) else gap - half <= tol_db <= gap + half})
    out = pd.DataFrame(rows, columns=CHOSEN_COLUMNS)
    out["gap_ci_includes_tol"] = out["gap_ci_includes_tol"].astype("boolean")
    return out


# --- the report's Markdown ------------------------------------------------------------


def _pm(mean: float, ci: float, digits: int = 2) -> str:
    """``mean ± ci`` (``mean`` alone when there is no interval)."""
    if math.isnan(mean):
        return "—"
    return f"{mean:.{digits}f}" if math.isnan(ci) else f"{mean:.{digits}f} ± {ci:.{digits}f}"


def _count(x: float) -> str:
    return "—" if math.isnan(x) else f"{int(x)}"


def _gap(row: pd.Series) -> str:
    return "0 (is the best)" if row.variant == row.best_variant else _pm(row.gap, row.gap_ci95)


def _settled(row: pd.Series, tol_db: float) -> str:
    if pd.isna(row.gap_ci_includes_tol):
        return "— (fewer than 2 runs or no spread)"
    return f"no: the CI reaches {tol_db:g} dB" if row.gap_ci_includes_tol else "yes"


def _unsettled(row: pd.Series) -> bool:
    """True unless the gap's CI shows the chosen variant within the tolerance."""
    return bool(pd.isna(row.gap_ci_includes_tol) or row.gap_ci_includes_tol)


def pair_sentences(chosen: pd.DataFrame) -> list[str]:
    """One sentence per pair of scenes comparing their chosen budgets (and iterations)."""
    out = []
    for (_, a), (_, b) in combinations(chosen.iterrows(), 2):
        small, large = sorted((a, b), key=lambda r: r.budget)
        if small.budget == large.budget:
            text = f"{small.scene_label} and {large.scene_label} both need {_count(small.budget)} Gaussians"
        else:
            text = (f"{small.scene_label} needs {_count(small.budget)} Gaussians,"
                    f" {large.scene_label} {_count(large.budget)}")
            if small.budget > 0:
                text += f" ({large.budget / small.budget:.3g}× as many)"
        if small.iterations != large.iterations:
            text += f"; iterations {_count(small.iterations)} against {_count(large.iterations)}"
        unsettled = [r.scene_label for r in (small, large) if _unsettled(r)]
        if unsettled:
            text += f"; not settled for {' and '.join(unsettled)} (the gap's CI reaches the tolerance)"
        out.append(text + ".")
    return out


def markdown(chosen: pd.DataFrame, tol_db: float = 0.1, metric: str = "psnr") -> str:
    """Per-scene table of ``smallest_per_scene`` followed by one sentence per scene pair."""
    name = PRETTY.get(metric, metric)
    lines = [f"| Scene | Smallest budget | Iterations | {name} (mean ± 95% CI) | Best variant | Best {name} |"
             f" Gap to best (± 95% CI) | Within {tol_db:g} dB settled? |",
             "|---|---:|---:|---:|---|---:|---:|---|"]
    for _, r in chosen.iterrows():
        lines.append(f"| {r.scene_label} | {_count(r.budget)} (`{r.variant}`) | {_count(r.iterations)} |"
                     f" {_pm(r['mean'], r.ci95)} | `{r.best_variant}` | {_pm(r.best_mean, r.best_ci95)} |"
                     f" {_gap(r)} | {_settled(r, tol_db)} |")
    sentences = pair_sentences(chosen)
    if sentences:
        lines += ["", *[f"- {s}" for s in sentences]]
    return "\n".join(lines)


def report_markdown(df: pd.DataFrame, tol_db: float = 0.1, metric: str = "psnr") -> str:
    """The report's section: heading, how to read it, the table and the scene comparisons."""
    sa = per_scene(df, metric)
    chosen = smallest_per_scene(sa, df, tol_db, metric)
    lines = [f"### Smallest budget within {tol_db:g} dB of the best, per scene", "",
             f"Per scene, the variant with the smallest Gaussian budget (then fewest iterations, then least"
             f" time) whose mean {PRETTY.get(metric, metric)} is within {tol_db:g} dB of that scene's best."
             " Gap = best mean − chosen mean, 95% CI from a Welch t-interval over the two variants' runs;"
             f" when it reaches {tol_db:g} dB, the runs cannot tell whether the budget is enough.", "",
             markdown(chosen, tol_db, metric)]
    empty = [s for s in dict.fromkeys(df.scene_label) if s not in set(chosen.scene_label)]
    if empty:
        lines += ["", f"No finished runs on: {', '.join(empty)}."]
    return "\n".join(lines)
