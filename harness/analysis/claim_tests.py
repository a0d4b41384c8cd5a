"""Claims tested on a study's runs: effect with CIs, the difference and equivalence tests.

A claim (``spec.study_schema.ClaimSpec``) names a metric, a comparison, the direction expected, the
smallest effect of interest (SESOI, fixed in the study file before the runs) and its family.
``evaluate(df, claims)`` takes the per-run frame (``report.results.runs_frame``; FINISHED runs
count) and returns one row per tested hypothesis with raw p-values; ``verdicts.decide`` then
corrects them over a named family and gives each row its verdict.

- ``mean``: ``a`` − ``b``, paired by (scene, seed) (``pair: seed``: runs sharing them share
  the initialisation and data order) with a paired t-test, or Welch (``pair: none``); no
  ``b``: a one-sample t-test of ``a`` against 0. Equivalence: TOST within ±SESOI. When its runs
  span 2 or more instances of one of its scenes (``spec.instances``; a claim's scene as written
  stands for all of them), the instance is the unit: each arm's mean per (instance_of, instance)
  over its seeds, then the same test on those means, paired by instance
  (``instance_unit.claim_test``); ``unit: seed`` keeps the seed (a run-to-run claim).
- ``variance``: the SD ratio std(a)/std(b), values centred per (variant, scene). Arms that
  share seeds (``pair: seed``) are paired: the Pitman–Morgan test (exact under normality, so
  its size is α at any n), equivalence by its two one-sided versions at [1/SESOI, SESOI], a
  paired bootstrap CI; unpaired arms: the Brown–Forsythe test (conservative at small n: its
  real size is below α) with a percentile bootstrap CI and equivalence when the bootstrap 90% CI
  lies within [1/SESOI, SESOI] (SESOI is a ratio here).
- ``interaction``: the per-seed difference a − b on ``scenes[0]`` minus the one on
  ``scenes[1]`` (Welch between the two sets).
- ``contrast``: each weighted sum of variants per (scene, seed), one-sample t; all must hold
  (an intersection–union test: p = the largest p, effect = the weakest contrast).
- ``decoupled`` and ``dissociated`` (existential, ``analysis.existential``): on some scene, a
  pair of variants equivalent (not worse) in ``metric`` whose ``versus`` differs (is worse).

A claim pooled over several scenes first tests the scene × variant interaction (one-way ANOVA
of the paired differences by scene); when it is significant and the scenes' effects have
opposite signs, the claim is tested per scene instead, each row labelled scene-dependent.
A claim whose ``requires`` metric is below its minimum on the runs is "not exercised".
Power and "runs needed" are for the SESOI, for the test used, at the α the claim faces in its
family (``verdicts.decide``): statsmodels' t-test power with the SD these runs show,
Pitman–Morgan power by simulation with the pairs' correlation (``stats.n_for_pm``),
Brown–Forsythe power by simulation (``stats.n_for_bf``). ``Result.power`` says which, with the
nuisance figure it needs.
An "≈" claim (``expect: equivalent``) is contradicted by the minimal-effect test (the effect
lies outside ±SESOI, ``stats.minimal_effect_p``), reproduced by TOST.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats as sps

from harness.analysis import stats
from harness.spec.instances import on_scenes
from harness.spec.study_schema import ClaimSpec

CONFIDENCE = 0.95
BOOT_SEED, BOOT_RESAMPLES = 0, 4000


@dataclass
class Result:
    """One tested hypothesis, before the family correction."""

    method: str
    n: str  # e.g. "5 pairs", "5 vs 5"
    effect: float
    ci: tuple[float, float]  # 95%
    ci90: tuple[float, float]  # 90%: the equivalence test's interval
    stat_name: str
    statistic: float
    p: float  # the difference test (two-sided)
    p_tost: float = math.nan  # equivalence within the SESOI
    power: tuple[str, float] = ("", math.nan)  # (test, SD or pair correlation) for the runs needed at the SESOI
    detail: str = ""
    p_outside: float = math.nan  # the effect lies outside ±SESOI (minimal-effect test; mean claims)
    # the effect's interval at any confidence level, from the same test or bootstrap as ``ci``: the
    # family's Holm step sets the level the verdict used (``verdicts.decide``: ``ci_adj_*``)
    interval: Callable[[float], tuple[float, float]] | None = None


def t_ci(res: object, level: float) -> tuple[float, float]:
    ci = res.confidence_interval(level)
    return float(ci.low), float(ci.high)


def t_interval(res: object) -> Callable[[float], tuple[float, float]]:
    """``level -> (low, high)`` of a scipy t-test result (its ``confidence_interval``)."""
    return lambda level: t_ci(res, level)


def _percentile(dist: np.ndarray) -> Callable[[float], tuple[float, float]]:
    """``level -> (low, high)``: the central percentile interval of a bootstrap distribution."""
    def interval(level: float) -> tuple[float, float]:
        tail = round((1.0 - level) / 2, 12)  # 0.95 -> 0.025 exactly, as the 95% CI always used
        with np.errstate(invalid="ignore"):  # inf − inf between two infinite draws: inf, not a warning
            return float(np.quantile(dist, tail)), float(np.quantile(dist, 1.0 - tail))
    return interval


def compare_means(a: np.ndarray, b: np.ndarray | None, paired: bool, sesoi: float) -> Result:
    """``a`` − ``b``: paired t (``a[i]`` with ``b[i]``), Welch, or one-sample t when ``b`` is None."""
    a = np.asarray(a, dtype=float)
    if b is None or paired:
        d = a if b is None else a - np.asarray(b, dtype=float)
        res = sps.ttest_1samp(d, 0.0)
        method = "one-sample t against 0" if b is None else "paired t (by scene and seed)"
        n = f"{len(d)} runs" if b is None else f"{len(d)} pairs"
        sd = float(d.std(ddof=1))
        return Result(method, n, float(d.mean()), t_ci(res, CONFIDENCE), t_ci(res, 0.90), "t", float(res.statistic),
                      float(res.pvalue), stats.tost_paired(d, sesoi), ("t_paired", sd),
                      p_outside=stats.minimal_effect_p(d, sesoi), interval=t_interval(res))
    b = np.asarray(b, dtype=float)
    res = sps.ttest_ind(a, b, equal_var=False)
    pooled = math.sqrt((a.var(ddof=1) + b.var(ddof=1)) / 2)
    above = sps.ttest_ind(a - sesoi, b, equal_var=False, alternative="greater").pvalue  # a − b > +sesoi
    below = sps.ttest_ind(a + sesoi, b, equal_var=False, alternative="less").pvalue  # a − b < −sesoi
    return Result("Welch t", f"{len(a)} vs {len(b)}", float(a.mean() - b.mean()), t_ci(res, CONFIDENCE),
                  t_ci(res, 0.90), "t", float(res.statistic), float(res.pvalue), stats.tost_ind(a, b, sesoi),
                  ("t_ind", pooled), p_outside=float(min(1.0, 2 * min(above, below))), interval=t_interval(res))


def _sd_ratio(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):  # a resample without spread: inf/nan, kept
        return np.std(x, ddof=1, axis=axis) / np.std(y, ddof=1, axis=axis)


def compare_variances(a: np.ndarray, b: np.ndarray, sesoi: float, names: tuple[str, str] = ("a", "b"),
                      paired: bool = False) -> Result:
    """std(``a``)/std(``b``). ``paired`` (``a[i]`` and ``b[i]`` share a seed): the Pitman–Morgan
    test and its two one-sided versions at [1/sesoi, sesoi], a paired bootstrap CI. Else the
    Brown–Forsythe test, a percentile bootstrap CI and equivalence when its 90% CI lies within
    [1/sesoi, sesoi]. Bootstraps use a fixed seed."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    # A resample that repeats one value has SD 0: against a spread arm its ratio is infinite, a valid
    # draw for the percentile CIs (scipy's standard error of the distribution, not used, is then
    # inf - inf); with 3 or 4 runs an arm some resamples repeat one value in both arms (0/0), no
    # ratio at all: left out of the percentiles, and scipy's warning about it (worded for BCa) says
    # nothing more.
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", sps.DegenerateDataWarning)
        boot = sps.bootstrap((a, b), _sd_ratio, n_resamples=BOOT_RESAMPLES, method="percentile", vectorized=True,
                             paired=paired, confidence_level=CONFIDENCE, rng=np.random.default_rng(BOOT_SEED))
        dist = boot.bootstrap_distribution[~np.isnan(boot.bootstrap_distribution)]
        ci90 = _percentile(dist)(0.90)
        ci = _percentile(dist)(CONFIDENCE)  # percentile, as scipy's
    va, vb = a.var(ddof=1), b.var(ddof=1)
    na, nb = names
    detail = f"SD {na} = {math.sqrt(va):.3g}, SD {nb} = {math.sqrt(vb):.3g}" + (
        f"; {1 - vb / va:.0%} of {na}'s variance is not in {nb}" if va > vb else "")
    if paired:
        rho = float(np.corrcoef(a, b)[0, 1]) if np.ptp(a) > 0 and np.ptp(b) > 0 else 0.0
        p = stats.pitman_morgan(a, b)
        r = sps.pearsonr(a + b, a - b) if np.ptp(a + b) > 0 and np.ptp(a - b) > 0 else None
        outside = min(1.0, 2 * min(stats.pitman_morgan(a, b, sesoi, "greater"),
                                   stats.pitman_morgan(a, b, 1.0 / sesoi, "less")))
        return Result("Pitman–Morgan (paired by seed); SD ratio, paired bootstrap CI", f"{len(a)} pairs",
                      float(_sd_ratio(a, b)), ci, ci90, "r", float(r.statistic) if r is not None else math.nan, p,
                      stats.pitman_morgan_tost(a, b, sesoi), ("pm", max(0.0, rho)),
                      detail + f"; the pairs correlate r = {rho:.2f}", p_outside=outside, interval=_percentile(dist))
    res = sps.levene(a, b, center="median")
    p_tost = float(max((dist <= 1 / sesoi).mean(), (dist >= sesoi).mean()))  # bootstrap TOST on the ratio
    return Result("Brown–Forsythe (Levene, median); SD ratio, bootstrap CI", f"{len(a)} vs {len(b)}",
                  float(_sd_ratio(a, b)), ci, ci90, "W", float(res.statistic), float(res.pvalue), p_tost,
                  ("bf", math.nan), detail, interval=_percentile(dist))


# --------------------------------------------------------------------------- selecting runs


def finished(df: pd.DataFrame, metric: str, scenes: tuple[str, ...] = ()) -> pd.DataFrame:
    """FINISHED runs with ``metric``, on ``scenes`` (all when empty): a scene as the study file
    writes it stands for every instance of it (``instance_of``, ``spec.instances``)."""
    if metric not in df.columns:
        return df.iloc[0:0].assign(**{metric: []})
    ok = df[(df.status == "FINISHED") & df[metric].notna()]
    return ok[on_scenes(ok, scenes)] if scenes else ok


def wide(df: pd.DataFrame, metric: str, variants: list[str], scenes: tuple[str, ...] = ()) -> pd.DataFrame:
    """``metric`` per (scene, seed) with one column per variant, rows where all finished."""
    ok = finished(df, metric, scenes)
    table = ok[ok.variant.isin(variants)].pivot_table(index=["scene", "seed"], columns="variant", values=metric,
                                                      aggfunc="first")
    if not set(variants) <= set(table.columns):
        return pd.DataFrame(columns=variants)
    return table[variants].dropna()


def missing(df: pd.DataFrame, claim: ClaimSpec) -> str:
    """Why a claim cannot be tested on ``df`` ("" when it can be tried)."""
    for m in (claim.metric, claim.versus):
        if m and m not in df.columns:
            return f"no run logged `{m}`"
    for v in claim.arms():
        if v not in set(df.variant):
            return f"variant `{v}` not in these runs"
    for s in claim.scenes:
        if s not in {*df.scene, *df.get("instance_of", ())}:
            return f"needs real data: {claim.needs}" if claim.needs else f"scene `{s}` not in these runs"
    return ""


def not_exercised(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> str:
    """Why the claim's mechanism is absent on these runs ("" when every ``requires`` is present).

    ``min``: the median of the metric over the claim's runs reaches it. ``above``: on some arm
    of the claim, the median of the metric minus its ground-truth level (another metric, or a
    number) reaches the metric's smallest effect of interest — the artefact shows at all."""
    from harness.spec.metrics import sesoi

    variants = list(claim.arms()) or list(dict.fromkeys(df.variant))
    for r in claim.requires:
        ok = finished(df, r.metric, scenes)
        ok = ok[ok.variant.isin(variants)]
        if ok.empty:
            return f"no run logged `{r.metric}`, which shows whether the mechanism is present"
        if r.min is not None:
            median = float(ok[r.metric].median())
            if median < r.min:
                return f"median `{r.metric}` {median:.4g} < {r.min:g}: the mechanism is absent on this scene"
            continue
        level = ok[r.above] if r.above in ok.columns else float(r.above)
        excess = (ok[r.metric] - level).groupby(ok.variant).median()
        threshold = sesoi(r.metric)[0]
        if not (excess >= threshold).any():
            worst = excess.idxmax()
            return (f"no arm shows the artefact: `{r.metric}` exceeds its ground-truth level ({r.above}) by at most"
                    f" {excess.max():.3g} (median, {worst}) < {threshold:g}, its smallest effect of interest")
    return ""


# --------------------------------------------------------------------------- one hypothesis


def pair_differences(df: pd.DataFrame, metric: str, a: str, b: str, scenes: tuple[str, ...]) -> pd.Series:
    """``a`` − ``b`` in ``metric`` per (scene, seed) where both finished (index: scene, seed)."""
    w = wide(df, metric, [a, b], scenes)
    return (w[a] - w[b]) if len(w) else pd.Series(dtype=float)


def paired_differences(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> pd.Series:
    """The claim's a − b per (scene, seed) where both finished (index: scene, seed)."""
    return pair_differences(df, claim.metric, claim.a, claim.b, scenes)


def contrast(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
    results = []
    for weights in claim.contrasts:
        w = wide(df, claim.metric, [v for v, _ in weights], scenes)
        if len(w) < 2:
            raise ValueError(f"{len(w)} (scene, seed) cells where every variant of a contrast finished (need 2)")
        values = sum(float(k) * w[v] for v, k in weights).to_numpy(dtype=float)
        res = compare_means(values, None, True, claim.sesoi)
        res.detail = " ".join(f"{k:+g}·{v}" for v, k in weights)
        results.append(res)
    # the contrast least favourable to the claim: the lowest t for "higher", the highest for "lower"
    # (a contrast clearly against the claim decides it, however clear the others are)
    worst = min(results, key=lambda r: r.statistic if claim.expect == "higher" else -r.statistic)
    return Result(f"contrasts, one-sample t each; all must hold (intersection–union, p = max of {len(results)})",
                  worst.n, worst.effect, worst.ci, worst.ci90, "t", worst.statistic, worst.p,
                  max(r.p_tost for r in results), worst.power,
                  "weakest contrast: " + worst.detail + "; all: " + "; ".join(
                      f"{r.detail} = {r.effect:+.3f}" for r in results), interval=worst.interval)


def spread(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
    """Variant ``a``'s run-to-run SD (centred per scene) with its chi-square 95% CI; no test."""
    ok = finished(df, claim.metric, scenes)
    ok = ok[ok.variant == claim.a]
    if len(ok) < 2:
        raise ValueError(f"{len(ok)} finished runs of {claim.a} (need 2)")
    values = (ok[claim.metric] - ok.groupby("scene")[claim.metric].transform("mean")).to_numpy(float)
    dof = len(values) - ok.scene.nunique()
    sd = float(math.sqrt((values ** 2).sum() / dof))
    def interval(level: float) -> tuple[float, float]:  # the chi-square interval of an SD
        tail = round((1.0 - level) / 2, 12)
        return tuple(float(math.sqrt(dof * sd * sd / sps.chi2.ppf(q, dof))) for q in (1.0 - tail, tail))

    return Result("run-to-run SD (centred per scene), chi-square CI; described, not tested", f"{len(values)} runs",
                  sd, interval(CONFIDENCE), interval(0.90), "", math.nan, math.nan, detail=f"{dof} degrees of freedom",
                  interval=interval)
