"""The paper's claims, tested on a study's runs: effect with 95% CI, statistic, Holm p, verdict.

A claim (``studies.ClaimSpec``, the ``claims:`` list of a study file) names a metric, a
comparison and the direction the paper expects. ``evaluate(df, claims)`` takes the report's
per-run frame (``aggregate.runs_frame``: one row per run, FINISHED runs count) and returns
one row per claim:

- ``mean``: variant ``a`` minus ``b``. Paired by seed (``pair: seed``, the default: every
  variant of a study runs with the same seeds, so runs sharing (scene, seed) share their
  initialisation and data order) with a paired t-test on the differences; ``pair: none``
  uses Welch's t-test. Several scenes are pooled (pairs pooled; unpaired: all runs). With
  no ``b``, a one-sample t-test of ``a`` against zero (per-run convention gaps).
- ``variance``: spread of ``a`` against ``b`` with the Brown–Forsythe test (scipy's Levene,
  ``center='median'``), never a t-test. Values are centred per (variant, scene) first, so
  pooling scenes adds no between-scene spread. Effect: std(a) − std(b), bootstrap CI.
- ``interaction``: the per-seed difference ``a`` − ``b`` on ``scenes[0]`` against the one on
  ``scenes[1]`` (difference of differences), Welch's t-test between the two sets.
- ``correlation``: Pearson r between ``metric`` and ``versus`` over every run, both centred
  per scene (does a better metric on the same scene go with a better ``versus``?). The
  claim ``weak`` is an equivalence test (two one-sided tests on Fisher's z) of |ρ| < threshold.

p-values are Holm-corrected over the claims of one study that could be tested. Verdict:
**reproduced** (Holm p < α and the effect in the claimed direction), **contradicted** (Holm
p < α, opposite direction; for ``weak``: the CI lies wholly outside ±threshold),
**inconclusive** otherwise, with the runs per arm a two-sided test at α would need for 80%
power at the observed effect; **not tested** when the runs a claim needs do not exist.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pandas as pd
from scipy import stats

from harness.spec.study import ClaimSpec

ALPHA = 0.05
POWER = 0.8
CONFIDENCE = 0.95
REPRODUCED, CONTRADICTED, INCONCLUSIVE, NOT_TESTED = "reproduced", "contradicted", "inconclusive", "not tested"
COLUMNS = ["id", "statement", "paper_number", "metric", "test", "comparison", "method", "n", "effect", "ci_low",
           "ci_high", "stat_name", "statistic", "p", "p_holm", "verdict", "n_needed", "note", "detail"]


@dataclass
class Comparison:
    """What one comparison found, before the Holm correction."""

    method: str
    n: str  # e.g. "5 pairs", "5 vs 5"
    effect: float
    ci: tuple[float, float]
    stat_name: str
    statistic: float
    p: float
    needed: Callable[[], float] = field(default=lambda: math.nan, repr=False)  # runs per arm for 80% power
    detail: str = ""  # e.g. the variance split of a variance claim
    strong: bool = False  # correlation only: the CI lies wholly outside +-threshold


# --------------------------------------------------------------------------- multiple testing


def holm(pvalues: np.ndarray | list[float]) -> np.ndarray:
    """Holm–Bonferroni adjusted p-values (step-down, monotone, capped at 1); NaN stays NaN."""
    p = np.asarray(pvalues, dtype=float)
    out = np.full_like(p, np.nan)
    ok = np.flatnonzero(~np.isnan(p))
    if len(ok) == 0:
        return out
    order = ok[np.argsort(p[ok], kind="stable")]
    m = len(order)
    adjusted = np.maximum.accumulate((m - np.arange(m)) * p[order])
    out[order] = np.minimum(adjusted, 1.0)
    return out


# --------------------------------------------------------------------------- power


def _smallest_n(power_at: Callable[[int], float], n_min: int = 2, n_max: int = 10**7) -> float:
    """Smallest integer n >= n_min with ``power_at(n) >= POWER`` (inf beyond n_max)."""
    if power_at(n_min) >= POWER:
        return float(n_min)
    lo, hi = n_min, n_min
    while power_at(hi) < POWER:
        lo, hi = hi, hi * 2
        if hi > n_max:
            return math.inf
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if power_at(mid) >= POWER else (mid, hi)
    return float(hi)


def n_for_t_test(d: float, paired: bool, alpha: float = ALPHA) -> float:
    """Runs per arm (pairs when ``paired``) for a two-sided t-test at ``alpha`` to reach 80%
    power at standardised effect ``d`` (Cohen's d; noncentral t)."""
    if not np.isfinite(d) or d == 0:
        return math.inf

    def power_at(n: int) -> float:
        df, nc = (n - 1, d * math.sqrt(n)) if paired else (2 * n - 2, d * math.sqrt(n / 2))
        tc = stats.t.ppf(1 - alpha / 2, df)
        return float(stats.nct.sf(tc, df, nc) + stats.nct.cdf(-tc, df, nc))

    return _smallest_n(power_at)


def n_for_variance_test(ratio: float, alpha: float = ALPHA) -> float:
    """Runs per arm for a two-sided F-test of equal variances at ``alpha`` to reach 80% power
    at variance ratio ``ratio`` (under normality; Brown–Forsythe needs somewhat more)."""
    if not np.isfinite(ratio) or ratio <= 0 or ratio == 1:
        return math.inf

    def power_at(n: int) -> float:
        lo, hi = stats.f.ppf(alpha / 2, n - 1, n - 1), stats.f.ppf(1 - alpha / 2, n - 1, n - 1)
        return float(stats.f.cdf(lo / ratio, n - 1, n - 1) + stats.f.sf(hi / ratio, n - 1, n - 1))

    return _smallest_n(power_at)


# --------------------------------------------------------------------------- the tests


def _ci(res: object) -> tuple[float, float]:
    ci = res.confidence_interval(CONFIDENCE)
    return float(ci.low), float(ci.high)


def compare_means(a: np.ndarray, b: np.ndarray | None, paired: bool) -> Comparison:
    """``a`` − ``b`` (means): paired t-test when ``paired`` (``a[i]`` pairs with ``b[i]``),
    Welch otherwise; ``b`` None: one-sample t-test of ``a`` against 0."""
    a = np.asarray(a, dtype=float)
    if b is None or paired:
        d = a if b is None else a - np.asarray(b, dtype=float)
        res = stats.ttest_1samp(d, 0.0)
        sd = d.std(ddof=1)
        method = "one-sample t against 0" if b is None else "paired t (by scene and seed)"
        n = f"{len(d)} runs" if b is None else f"{len(d)} pairs"
        return Comparison(method, n, float(d.mean()), _ci(res), "t", float(res.statistic), float(res.pvalue),
                          lambda: n_for_t_test(float(d.mean() / sd) if sd > 0 else math.nan, paired=True))
    b = np.asarray(b, dtype=float)
    res = stats.ttest_ind(a, b, equal_var=False)
    pooled = math.sqrt((a.var(ddof=1) + b.var(ddof=1)) / 2)
    effect = float(a.mean() - b.mean())
    return Comparison("Welch t", f"{len(a)} vs {len(b)}", effect, _ci(res), "t", float(res.statistic),
                      float(res.pvalue), lambda: n_for_t_test(effect / pooled if pooled > 0 else math.nan, paired=False))


def _std_diff(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.std(x, ddof=1, axis=axis) - np.std(y, ddof=1, axis=axis)


def compare_variances(a: np.ndarray, b: np.ndarray, seed: int = 0, names: tuple[str, str] = ("a", "b")
                      ) -> Comparison:
    """std(``a``) − std(``b``): Brown–Forsythe test (Levene, median centre), percentile
    bootstrap CI of the std difference (fixed seed: reports are reproducible). ``detail``
    gives both variances and, when ``a`` varies more, the share of its variance ``b`` lacks
    (fixed vs free initialisation: the initialisation's share)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    res = stats.levene(a, b, center="median")
    boot = stats.bootstrap((a, b), _std_diff, n_resamples=4000, method="percentile",
                           confidence_level=CONFIDENCE, rng=np.random.default_rng(seed))  # fmt: skip
    va, vb = a.var(ddof=1), b.var(ddof=1)
    ratio = va / vb if vb > 0 else math.nan
    # b nested in a (fixed vs free init): the part of a's variance b does not have
    na, nb = names
    split = f"var {na} = {va:.3g}, var {nb} = {vb:.3g}" + (
        f"; {1 - vb / va:.0%} of {na}'s variance is not in {nb}" if va > vb else "")
    return Comparison("Brown–Forsythe (Levene, median)", f"{len(a)} vs {len(b)}", float(_std_diff(a, b)),
                      (float(boot.confidence_interval.low), float(boot.confidence_interval.high)), "W",
                      float(res.statistic), float(res.pvalue), lambda: n_for_variance_test(ratio), split)


def compare_interaction(d1: np.ndarray, d2: np.ndarray) -> Comparison:
    """Difference of differences: mean(``d1``) − mean(``d2``), Welch t between the per-seed
    differences of the two scenes."""
    res = compare_means(d1, d2, paired=False)
    res.method = "Welch t on per-seed differences (difference of differences)"
    return res


def weak_correlation(x: np.ndarray, y: np.ndarray, threshold: float) -> Comparison:
    """Pearson r with its CI; p of the equivalence test |ρ| < ``threshold`` (two one-sided
    tests on Fisher's z); ``strong`` when the CI lies wholly outside ±threshold."""
    res = stats.pearsonr(x, y)
    r, n = float(res.statistic), len(x)
    lo, hi = _ci(res)
    z, zt, se = math.atanh(max(min(r, 1 - 1e-12), -1 + 1e-12)), math.atanh(threshold), 1 / math.sqrt(n - 3)
    p = max(stats.norm.cdf((z - zt) / se), stats.norm.sf((z + zt) / se))
    gap = zt - abs(z)  # room left inside the band
    need = math.ceil(3 + ((stats.norm.ppf(1 - ALPHA) + stats.norm.ppf(POWER)) / gap) ** 2) if gap > 0 else math.inf
    return Comparison(f"Pearson r, equivalence |ρ| < {threshold:g} (TOST, Fisher z)", f"{n} runs", r, (lo, hi),
                      "r", r, float(p), lambda: float(need), strong=lo > threshold or hi < -threshold)


# --------------------------------------------------------------------------- claims on runs


def _finished(df: pd.DataFrame, metric: str, scenes: tuple[str, ...]) -> pd.DataFrame:
    if metric not in df.columns:
        return df.iloc[0:0].assign(**{metric: []})
    ok = df[(df.status == "FINISHED") & df[metric].notna()]
    return ok[ok.scene.isin(scenes)] if scenes else ok


def _paired(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> pd.DataFrame:
    """Columns a and b of ``metric`` for every (scene, seed) where both variants finished."""
    ok = _finished(df, claim.metric, scenes)
    wide = ok[ok.variant.isin([claim.a, claim.b])].pivot_table(
        index=["scene", "seed"], columns="variant", values=claim.metric, aggfunc="first")
    if claim.a not in wide or claim.b not in wide:
        return pd.DataFrame(columns=["a", "b"])
    return wide[[claim.a, claim.b]].dropna().set_axis(["a", "b"], axis=1)


def _missing(df: pd.DataFrame, claim: ClaimSpec) -> str:
    """Why a claim cannot be tested on ``df`` ("" when it can be tried)."""
    if claim.metric not in df.columns or (claim.versus and claim.versus not in df.columns):
        return f"no run logged `{claim.versus if claim.metric in df.columns else claim.metric}`"
    for v in (claim.a, claim.b):
        if v and v not in set(df.variant):
            return f"variant `{v}` not in these runs"
    for s in claim.scenes:
        if s not in set(df.scene):
            return f"scene `{s}` not in these runs"
    return ""


def compare(df: pd.DataFrame, claim: ClaimSpec) -> Comparison:
    """The claim's comparison on the FINISHED runs of ``df``; ValueError when too few runs."""
    if claim.test == "correlation":
        ok = _finished(df, claim.metric, claim.scenes)
        ok = ok[ok[claim.versus].notna()] if claim.versus in ok else ok.iloc[0:0]
        if claim.a:
            ok = ok[ok.variant.isin([claim.a, claim.b] if claim.b else [claim.a])]
        if len(ok) < 4:
            raise ValueError(f"{len(ok)} runs with both metrics (need 4)")
        centred = ok[[claim.metric, claim.versus]] - ok.groupby("scene")[[claim.metric, claim.versus]].transform("mean")
        return weak_correlation(centred[claim.metric].to_numpy(), centred[claim.versus].to_numpy(),
                                     claim.threshold)  # fmt: skip
    if claim.test == "interaction":
        diffs = [_paired(df, claim, (s,)) for s in claim.scenes]
        d1, d2 = ((w.a - w.b).to_numpy(dtype=float) for w in diffs)
        if min(len(d1), len(d2)) < 2:
            raise ValueError(f"{len(d1)} and {len(d2)} seed pairs on the two scenes (need 2 each)")
        return compare_interaction(d1, d2)
    ok = _finished(df, claim.metric, claim.scenes)
    if claim.test == "mean" and claim.b and claim.pair == "seed":
        w = _paired(df, claim, claim.scenes)
        if len(w) < 2:
            raise ValueError(f"{len(w)} (scene, seed) pairs where both variants finished (need 2)")
        return compare_means(w.a.to_numpy(dtype=float), w.b.to_numpy(dtype=float), paired=True)
    if claim.test == "variance":
        ok = ok.assign(**{claim.metric: ok[claim.metric] - ok.groupby(["variant", "scene"])[claim.metric].transform("mean")})
    a = ok.loc[ok.variant == claim.a, claim.metric].to_numpy(dtype=float)
    b = ok.loc[ok.variant == claim.b, claim.metric].to_numpy(dtype=float) if claim.b else None
    if len(a) < 2 or (b is not None and len(b) < 2):
        raise ValueError(f"{len(a)} vs {0 if b is None else len(b)} finished runs (need 2 each)")
    if claim.test == "variance":
        return compare_variances(a, b, names=(claim.a, claim.b))
    return compare_means(a, b, paired=False)


def comparison_text(claim: ClaimSpec) -> str:
    """What is compared, in words: ``cc − baseline (studio)``."""
    where = f" ({', '.join(claim.scenes)})" if claim.scenes and claim.test != "interaction" else ""
    if claim.test == "correlation":
        return f"r({claim.metric}, {claim.versus}) within scene{where}"
    if claim.test == "variance":
        return f"std {claim.a} − std {claim.b}{where}"
    if claim.test == "interaction":
        return f"({claim.a} − {claim.b}) on {claim.scenes[0]} − on {claim.scenes[1]}"
    return f"{claim.a} − {claim.b or '0'}{where}"


def verdict(p_holm: float, effect: float, expect: str, strong: bool = False, alpha: float = ALPHA) -> str:
    """reproduced / contradicted / inconclusive from the Holm p and the effect's sign."""
    if expect == "weak":
        return REPRODUCED if p_holm < alpha else CONTRADICTED if strong else INCONCLUSIVE
    if not p_holm < alpha or not np.isfinite(effect) or effect == 0:
        return INCONCLUSIVE
    return REPRODUCED if (effect > 0) == (expect == "higher") else CONTRADICTED


def evaluate(df: pd.DataFrame, claims: tuple[ClaimSpec, ...] | list[ClaimSpec], alpha: float = ALPHA
             ) -> pd.DataFrame:
    """One row per claim (``COLUMNS``): effect, 95% CI, statistic, p, Holm p over the claims
    tested, verdict and the runs per arm needed when inconclusive."""
    rows, results = [], []
    for c in claims:
        row = {"id": c.id, "statement": c.statement, "paper_number": c.paper_number, "metric": c.metric,
               "test": c.test, "comparison": comparison_text(c), "method": "", "n": "", "effect": math.nan,
               "ci_low": math.nan, "ci_high": math.nan, "stat_name": "", "statistic": math.nan, "p": math.nan,
               "p_holm": math.nan, "verdict": NOT_TESTED, "n_needed": math.nan, "note": _missing(df, c), "detail": ""}
        res = None
        if not row["note"]:
            try:
                res = compare(df, c)
            except ValueError as err:
                row["note"] = str(err)
        if res is not None:
            row.update(method=res.method, n=res.n, effect=res.effect, ci_low=res.ci[0], ci_high=res.ci[1],
                       stat_name=res.stat_name, statistic=res.statistic, p=res.p, detail=res.detail)
            if not np.isfinite(res.p):
                row["note"] = "no spread in the data: the test is undefined"
        rows.append(row)
        results.append(res)
    out = pd.DataFrame(rows, columns=COLUMNS)
    out["p_holm"] = holm(out["p"].to_numpy(dtype=float)) if len(out) else []
    for i, (c, res) in enumerate(zip(claims, results)):
        if res is None or not np.isfinite(res.p):
            continue
        v = verdict(float(out.at[i, "p_holm"]), res.effect, c.expect, res.strong, alpha)
        out.at[i, "verdict"] = v
        if v == INCONCLUSIVE:
            out.at[i, "n_needed"] = res.needed()
    return out
