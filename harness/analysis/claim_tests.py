"""Claims tested on a study's runs: effect with CIs, the difference and equivalence tests.

A claim (``spec.study_schema.ClaimSpec``) names a metric, a comparison, the direction expected, the
smallest effect of interest (SESOI, fixed in the study file before the runs) and its family.
``evaluate(df, claims)`` takes the per-run frame (``report.results.runs_frame``; FINISHED runs
count) and returns one row per tested hypothesis with raw p-values; ``verdicts.decide`` then
corrects them over a named family and gives each row its verdict.

- ``mean``: ``a`` − ``b``, paired by (scene, seed) (``pair: seed``: runs sharing them share
  the initialisation and data order) with a paired t-test, or Welch (``pair: none``); no
  ``b``: a one-sample t-test of ``a`` against 0. Equivalence: TOST within ±SESOI.
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
- ``decoupled`` (existential): on some scene, a pair of variants equivalent in ``metric``
  within ±SESOI (TOST) whose ``versus`` differs (paired t); p per pair = the larger of the
  two, Bonferroni over the pairs tried.

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

import itertools
import math
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats as sps

from harness.analysis import stats
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


def _ci(res: object, level: float) -> tuple[float, float]:
    ci = res.confidence_interval(level)
    return float(ci.low), float(ci.high)


def _interval(res: object) -> Callable[[float], tuple[float, float]]:
    """``level -> (low, high)`` of a scipy t-test result (its ``confidence_interval``)."""
    return lambda level: _ci(res, level)


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
        return Result(method, n, float(d.mean()), _ci(res, CONFIDENCE), _ci(res, 0.90), "t", float(res.statistic),
                      float(res.pvalue), stats.tost_paired(d, sesoi), ("t_paired", sd),
                      p_outside=stats.minimal_effect_p(d, sesoi), interval=_interval(res))
    b = np.asarray(b, dtype=float)
    res = sps.ttest_ind(a, b, equal_var=False)
    pooled = math.sqrt((a.var(ddof=1) + b.var(ddof=1)) / 2)
    above = sps.ttest_ind(a - sesoi, b, equal_var=False, alternative="greater").pvalue  # a − b > +sesoi
    below = sps.ttest_ind(a + sesoi, b, equal_var=False, alternative="less").pvalue  # a − b < −sesoi
    return Result("Welch t", f"{len(a)} vs {len(b)}", float(a.mean() - b.mean()), _ci(res, CONFIDENCE),
                  _ci(res, 0.90), "t", float(res.statistic), float(res.pvalue), stats.tost_ind(a, b, sesoi),
                  ("t_ind", pooled), p_outside=float(min(1.0, 2 * min(above, below))), interval=_interval(res))


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
    """FINISHED runs with ``metric``, on ``scenes`` (all when empty)."""
    if metric not in df.columns:
        return df.iloc[0:0].assign(**{metric: []})
    ok = df[(df.status == "FINISHED") & df[metric].notna()]
    return ok[ok.scene.isin(scenes)] if scenes else ok


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
        if s not in set(df.scene):
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


def _contrast(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
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


def _seed_aligned(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...], pairs: Callable
                  ) -> Iterator[tuple[str, str, str, pd.DataFrame, pd.DataFrame]]:
    """``(scene, a, b, x, y)`` for every scene and pair ``pairs(variants, 2)`` (combinations or
    permutations) of the study's variants (``claim.among`` only, when it names some) with at least
    3 seeds that logged both metrics: ``x`` of ``claim.metric``
    and ``y`` of ``claim.versus``, wide by variant, on the same seeds."""
    variants = [v for v in dict.fromkeys(df.variant) if not claim.among or v in claim.among]
    for scene in scenes or tuple(dict.fromkeys(df.scene)):
        for va, vb in pairs(variants, 2):
            x = wide(df, claim.metric, [va, vb], (scene,))
            y = wide(df, claim.versus, [va, vb], (scene,)).reindex(x.index).dropna()
            if len(y) >= 3:
                yield scene, va, vb, x.loc[y.index], y


def _decoupled(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
    tried = []
    for scene, va, vb, x, y in _seed_aligned(df, claim, scenes, itertools.combinations):
        p_equal = stats.tost_paired((x[va] - x[vb]).to_numpy(float), claim.sesoi)
        dy = (y[va] - y[vb]).to_numpy(float)
        differs = sps.ttest_1samp(dy, 0.0)
        tried.append((max(p_equal, float(differs.pvalue)), scene, va, vb, dy, differs, p_equal))
    if not tried:
        raise ValueError("no scene with 3 seeds of two variants that logged both metrics")
    p, scene, va, vb, dy, res, p_equal = min(tried, key=lambda t: t[0])
    return Result(f"existential: per scene and variant pair, TOST of {claim.metric} within ±{claim.sesoi:g} and"
                  f" paired t of {claim.versus}; p = max of the two, Bonferroni over {len(tried)} pairs",
                  f"{len(dy)} pairs", float(dy.mean()), _ci(res, CONFIDENCE), _ci(res, 0.90), "t",
                  float(res.statistic), min(1.0, p * len(tried)), math.nan, ("", math.nan),
                  f"best pair {va} vs {vb} on {scene}: {claim.metric} equivalent (TOST p = {p_equal:.2g}),"
                  f" {claim.versus} differs by {dy.mean():+.3g} (p = {res.pvalue:.2g})", interval=_interval(res))


def _dissociated(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
    """On some scene, an ordered pair (x, y): x is not worse than y in ``metric`` by the SESOI
    (one-sided t against −SESOI on the better side) yet worse in ``versus`` (one-sided paired t);
    p per pair = the larger of the two, Bonferroni over every ordered pair tried."""
    from harness.spec.metrics import lower_is_better

    sign_m = -1.0 if lower_is_better(claim.metric) else 1.0  # turns "better" into "higher"
    sign_v = -1.0 if lower_is_better(claim.versus) else 1.0
    tried = []
    for scene, vx, vy, x, y in _seed_aligned(df, claim, scenes, itertools.permutations):
        dm = sign_m * (x[vx] - x[vy]).to_numpy(float)  # > 0: x renders better
        dv = sign_v * (y[vx] - y[vy]).to_numpy(float)  # < 0: x moves worse
        p_not_worse = float(sps.ttest_1samp(dm, -claim.sesoi, alternative="greater").pvalue)
        worse = sps.ttest_1samp(dv, 0.0, alternative="less")
        tried.append((max(p_not_worse, float(worse.pvalue)), scene, vx, vy, dm, dv, p_not_worse))
    if not tried:
        raise ValueError("no scene with 3 seeds of two variants that logged both metrics")
    p, scene, vx, vy, dm, dv, p_not_worse = min(tried, key=lambda t: t[0])
    raw = sign_v * dv  # in the metric's own direction
    res = sps.ttest_1samp(raw, 0.0)
    return Result(f"existential: per scene and ordered variant pair, {claim.metric} not worse by ±{claim.sesoi:g}"
                  f" (one-sided t) and {claim.versus} worse (one-sided paired t); p = the larger, Bonferroni over"
                  f" {len(tried)} pairs", f"{len(dv)} pairs", float(raw.mean()), _ci(res, CONFIDENCE),
                  _ci(res, 0.90), "t", float(res.statistic), min(1.0, p * len(tried)), math.nan, ("", math.nan),
                  f"best pair {vx} vs {vy} on {scene}: {claim.metric} {sign_m * dm.mean():+.3g} (not worse by"
                  f" {claim.sesoi:g}: p = {p_not_worse:.2g}), {claim.versus} {raw.mean():+.3g} (worse)",
                  interval=_interval(res))


def _spread(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
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


def compare(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
    """The claim's test on the FINISHED runs of ``df`` on ``scenes``; ValueError when too few runs."""
    if claim.test == "contrast":
        return _contrast(df, claim, scenes)
    if claim.test == "decoupled":
        return _decoupled(df, claim, scenes)
    if claim.test == "dissociated":
        return _dissociated(df, claim, scenes)
    if claim.test == "spread":
        return _spread(df, claim, scenes)
    if claim.test == "interaction":
        pairs = claim.pairs or ((claim.a, claim.b),) * len(claim.scenes)
        d1, d2 = (pair_differences(df, claim.metric, a, b, (s,)).to_numpy(dtype=float)
                  for s, (a, b) in zip(claim.scenes, pairs))
        if min(len(d1), len(d2)) < 2:
            raise ValueError(f"{len(d1)} and {len(d2)} seed pairs on the two scenes (need 2 each)")
        res = compare_means(d1, d2, paired=False, sesoi=claim.sesoi)
        res.method = "Welch t on per-seed differences (difference of differences)"
        return res
    if claim.test == "mean" and claim.b and claim.pair == "seed":
        d = paired_differences(df, claim, scenes)
        if len(d) < 2:
            raise ValueError(f"{len(d)} (scene, seed) pairs where both variants finished (need 2)")
        res = compare_means(d.to_numpy(dtype=float), None, True, claim.sesoi)
        res.method, res.n = "paired t (by scene and seed)", f"{len(d)} pairs"
        return res
    ok = finished(df, claim.metric, scenes)
    if claim.test == "variance":  # centred per cell: pooling scenes adds no between-scene spread
        ok = ok.assign(**{claim.metric: ok[claim.metric] - ok.groupby(["variant", "scene"])[claim.metric].transform("mean")})
    a = ok.loc[ok.variant == claim.a, claim.metric].to_numpy(dtype=float)
    b = ok.loc[ok.variant == claim.b, claim.metric].to_numpy(dtype=float) if claim.b else None
    if len(a) < 2 or (b is not None and len(b) < 2):
        raise ValueError(f"{len(a)} vs {0 if b is None else len(b)} finished runs (need 2 each)")
    if claim.test == "variance":
        if claim.pair == "seed":  # arms that share seeds: the pairs' spreads compared as pairs
            w = ok[ok.variant.isin([claim.a, claim.b])].pivot_table(
                index=["scene", "seed"], columns="variant", values=claim.metric, aggfunc="first").dropna()
            if len(w) < 3 or not {claim.a, claim.b} <= set(w.columns):
                raise ValueError(f"{len(w)} (scene, seed) pairs where both arms finished (need 3)")
            return compare_variances(w[claim.a].to_numpy(float), w[claim.b].to_numpy(float), claim.sesoi,
                                     names=(claim.a, claim.b), paired=True)
        return compare_variances(a, b, claim.sesoi, names=(claim.a, claim.b))
    return compare_means(a, b, paired=False, sesoi=claim.sesoi)


def scene_split(df: pd.DataFrame, claim: ClaimSpec) -> tuple[float, dict[str, float]]:
    """(heterogeneity p, per-scene mean effect) of a paired claim pooled over several scenes."""
    if claim.test not in ("mean", "contrast") or not claim.b or claim.pair != "seed" or len(claim.scenes) == 1:
        return math.nan, {}
    d = paired_differences(df, claim, claim.scenes)
    if d.empty:
        return math.nan, {}
    scenes = d.index.get_level_values("scene")
    order = [s for s in (claim.scenes or tuple(dict.fromkeys(scenes))) if s in set(scenes)]
    by_scene = {s: d[scenes == s].to_numpy(dtype=float) for s in order}
    return stats.heterogeneity(list(by_scene.values())), {s: float(v.mean()) for s, v in by_scene.items()}
