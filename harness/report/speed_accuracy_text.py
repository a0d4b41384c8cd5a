"""Speed against accuracy per scene in a report: the smallest-budget table, one sentence per
pair of scenes (per method), and what the second method costs and buys against the first
(numbers from ``analysis.speed_accuracy_scenes``)."""

from __future__ import annotations

import math
from itertools import combinations

import pandas as pd

from harness.analysis.aggregate import size_tolerance
from harness.analysis.speed_accuracy_scenes import method_comparison, per_scene, smallest_per_scene
from harness.spec.metrics import label


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
    if unsaturated(row):
        return "— (the largest budget tried: no saturation within the grid)"
    if row.variant == row.best_variant:
        return "— (the best itself)"
    if pd.isna(row.gap_ci_includes_tol):
        return "— (fewer than 2 runs or no spread)"
    return f"no: the CI reaches {tol_db:g} dB" if row.gap_ci_includes_tol else "yes"


def unsaturated(row: pd.Series) -> bool:
    """The chosen budget is the best and the largest tried: the grid shows no saturation."""
    return bool(row.variant == row.best_variant and row.budget >= row.largest_budget)


def _unsettled(row: pd.Series) -> bool:
    """True unless the gap's CI shows the chosen variant within the tolerance."""
    return bool(pd.isna(row.gap_ci_includes_tol) or row.gap_ci_includes_tol)


def pair_sentences(chosen: pd.DataFrame) -> list[str]:
    """One sentence per pair of scenes comparing their chosen budgets (and iterations), per
    method (each sentence starts with the method's name when the grid names methods)."""
    if "method" in chosen and chosen.method.nunique() > 1:
        return [f"`{m}`: {text}" for m, sub in chosen.groupby("method", sort=False)
                for text in pair_sentences(sub.drop(columns="method"))]
    out = []
    for (_, a), (_, b) in combinations(chosen.iterrows(), 2):
        small, large = sorted((a, b), key=lambda r: r.budget)
        open_ = [r for r in (small, large) if unsaturated(r)]
        if len(open_) == 2:
            out.append(f"Neither {small.scene_label} nor {large.scene_label} saturates within the grid (each is"
                       " best at its largest budget).")
            continue
        if open_:
            done = small if open_[0] is large else large
            out.append(f"{done.scene_label} needs {_count(done.budget)} Gaussians; {open_[0].scene_label} still gains"
                       f" at {_count(open_[0].budget)}, its largest budget tried"
                       + ("; not settled for " + done.scene_label + " (the gap's CI reaches the tolerance)."
                          if _unsettled(done) else "."))
            continue
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


def markdown(chosen: pd.DataFrame, tol_db: float | None = None, metric: str = "psnr") -> str:
    """Per-scene table of ``smallest_per_scene`` followed by one sentence per scene pair."""
    tol_db = size_tolerance(metric) if tol_db is None else tol_db
    name = label(metric)
    named = "method" in chosen and chosen.method.astype(bool).any()
    lines = [f"| Scene |{' Method |' if named else ''} Smallest budget | Iterations | {name} (mean ± 95% CI) |"
             f" Best variant | Best {name} | Gap to best (± 95% CI) | Within {tol_db:g} dB settled? |",
             f"|---|{'---|' if named else ''}---:|---:|---:|---|---:|---:|---|"]
    for _, r in chosen.iterrows():
        lines.append(f"| {r.scene_label} |{f' `{r.method}` |' if named else ''} {_count(r.budget)} (`{r.variant}`) |"
                     f" {_count(r.iterations)} |"
                     f" {_pm(r['mean'], r.ci95)} | `{r.best_variant}` | {_pm(r.best_mean, r.best_ci95)} |"
                     f" {_gap(r)} | {_settled(r, tol_db)} |")
    sentences = pair_sentences(chosen)
    if sentences:
        lines += ["", *[f"- {s}" for s in sentences]]
    return "\n".join(lines)


def report_markdown(df: pd.DataFrame, tol_db: float | None = None, metric: str = "psnr", on: str = "") -> str:
    """The report's section: heading (``on`` names the metric in it), how to read it, the table
    and the scene comparisons."""
    tol_db = size_tolerance(metric) if tol_db is None else tol_db
    sa = per_scene(df, metric)
    chosen = smallest_per_scene(sa, df, tol_db, metric)
    lines = [f"### Smallest budget within {tol_db:g} dB of the best, per scene{on}", "",
             f"Per scene (and method), the variant with the smallest Gaussian budget (then fewest iterations,"
             f" then least time) whose mean {label(metric)} is within {tol_db:g} dB of that scene's (and"
             " method's) best."
             " Gap = best mean − chosen mean, 95% CI from a Welch t-interval over the two variants' runs;"
             f" when it reaches {tol_db:g} dB, the runs cannot tell whether the budget is enough.", "",
             markdown(chosen, tol_db, metric)]
    empty = [s for s in dict.fromkeys(df.scene_label) if s not in set(chosen.scene_label)]
    if empty:
        lines += ["", f"No finished runs on: {', '.join(empty)}."]
    return "\n".join(lines)


def colour_aligned_markdown(df: pd.DataFrame, tol_db: float | None = None) -> str:
    """The same search on colour-aligned PSNR, and why it is shown beside the raw one."""
    return "\n".join([
        report_markdown(df, tol_db, "psnr_cc", on=", on colour-aligned PSNR"), "",
        "The held-out camera's own colour transform is unknown to the model (colour correction learns"
        " the training cameras'), so raw PSNR carries an error that no budget removes and flattens where"
        " that error dominates. Colour-aligned PSNR (`psnr_cc`: a least-squares affine colour map of the"
        " render onto the ground truth first) shows what the model itself still gains; a budget that is"
        " enough on raw PSNR but not here saturates the metric, not the scene."])


def _ci(row: pd.Series, m: str, digits: int) -> str:
    d, lo, hi = row[f"d_{m}"], row[f"d_{m}_low"], row[f"d_{m}_high"]
    if math.isnan(d):
        return "—"
    return f"{d:+.{digits}f}" + ("" if math.isnan(lo) else f" [{lo:+.{digits}f}, {hi:+.{digits}f}]")


def _ratio(x: float) -> str:
    return "—" if math.isnan(x) else f"×{x:.2f}"


def method_markdown(df: pd.DataFrame, baseline: str = "") -> str:
    """What the other method costs and buys against the baseline variant's, per scene and grid
    cell: quality differences with 95% Welch intervals, cost ratios; "" unless the grid has two
    methods."""
    from harness.analysis.speed_accuracy_scenes import method_of

    cmp = method_comparison(df, method_of(baseline))
    if cmp.empty:
        return ""
    first, second = cmp["first"].iloc[0], cmp["second"].iloc[0]
    lines = [f"### What `{second}` costs and buys against `{first}`, per scene", "",
             f"Same scene, budget and iterations; quality: `{second}` minus `{first}` (mean difference, 95% Welch"
             f" interval over the runs); cost: `{second}` over `{first}` (ratio of means). Alive Gaussians leave"
             " out those drawn nowhere in the clip. Render FPS: `study measure`, one model at a time.", "",
             "| Scene | Budget | Iterations | Δ PSNR (dB) | Δ colour-aligned PSNR (dB) | Δ LPIPS-Alex (lower is"
             " better) | training time | render FPS, 1 thread (> 1: faster) | model bytes | alive Gaussians |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for _, r in cmp.iterrows():
        lines.append(f"| {r.scene_label} | {_count(r.budget)} | {_count(r.iterations)} | {_ci(r, 'psnr', 2)} |"
                     f" {_ci(r, 'psnr_cc', 2)} | {_ci(r, 'lpips_alex', 4)} | {_ratio(r.r_train_seconds)} |"
                     f" {_ratio(r.r_render_fps_1thread)} | {_ratio(r.r_model_bytes)} | {_ratio(r.r_n_alive)} |")
    return "\n".join(lines)
