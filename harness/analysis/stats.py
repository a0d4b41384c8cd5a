"""The statistics behind the verdicts, from scipy and statsmodels (nothing hand-rolled that
either already provides).

- ``family_adjust``: Holm (or Benjamini–Hochberg) over a named family of claims
  (``statsmodels.stats.multitest.multipletests``); ``union_adjust``: one Holm over a family's
  difference *and* equivalence hypotheses together, so that everything the family can reject
  shares one family-wise error rate (two separate Holm runs allow up to 2α);
  ``holm_levels``: the α of the Holm step that decided each of them, the level of the interval
  dual to that decision;
- ``tost_paired``, ``tost_one_sample``, ``tost_ind``: equivalence within ±SESOI, two one-sided
  tests (``statsmodels.stats.weightstats``);
- ``minimal_effect_p``: the test that a mean difference lies *outside* ±SESOI (the
  counterpart of TOST, for "≈" claims: ``scipy.stats.ttest_1samp`` against ±SESOI, one-sided);
- ``n_for_t``: runs per arm (or pairs) for 80% power of the test actually used, at the
  smallest effect of interest and at the α the claim faces — prospective, never from the
  observed effect (``statsmodels.stats.power``);
- ``iu_power`` / ``n_for_iu``: the power of an intersection–union test (both of two one-sided
  paired t-tests must reject: the existential ``dissociated`` claim), bounded below by
  p₁ + p₂ − 1 (Fréchet), which needs no assumption on how the two metrics correlate;
- ``pitman_morgan``: the spread of two *paired* samples (runs sharing a seed): SD(a)/SD(b) = r
  ⇔ corr(a + r·b, a − r·b) = 0, Pearson's exact test under normality
  (``scipy.stats.pearsonr``), two-sided against r = 1 and one-sided at ±r for equivalence;
  ``pm_power`` / ``n_for_pm`` by simulation;
- ``bf_power`` / ``n_for_bf``: the power of the Brown–Forsythe test (``scipy.stats.levene``,
  median centre) by simulation, since it has no closed form (normal samples, stated seed and
  number of draws);
- ``heterogeneity``: do the per-scene effects differ (the scene × variant interaction of a
  paired design: one-way ANOVA of the paired differences by scene);
- ``paper_evidence``: is the paper's own difference distinguishable from its own run-to-run
  spread (``scipy.stats.ttest_ind_from_stats``, Welch)?
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import stats

ALPHA = 0.05
POWER = 0.8
BF_DRAWS = 2000  # Monte-Carlo draws per simulated power
BF_SEED = 20261124
N_MAX = 1000  # runs per arm beyond which "needed" is reported as more than this


def family_adjust(pvalues: list[float] | np.ndarray, method: str = "holm") -> np.ndarray:
    """Adjusted p-values over one family; NaN (untested) stays NaN and is not counted.

    statsmodels' Holm branch ends with ``gc.collect()`` (statsmodels/stats/multitest.py, 0.15):
    a full collection on every call, 0.1–0.2 s in a process holding a report's frames, and
    ``study index`` and the verdict tests adjust thousands of families. The call is made with
    ``gc.collect`` a no-op for its duration; the numbers are statsmodels' own."""
    import gc
    from unittest import mock

    from statsmodels.stats import multitest

    p = np.asarray(pvalues, dtype=float)
    out = np.full_like(p, np.nan)
    ok = np.flatnonzero(np.isfinite(p))
    if len(ok):
        with mock.patch.object(gc, "collect", _no_collection):
            out[ok] = multitest.multipletests(p[ok], alpha=ALPHA, method=method)[1]
    return out


def _no_collection(*args: object) -> int:
    """``gc.collect``'s stand-in while ``multipletests`` runs: collects nothing, as it reports."""
    return 0


def union_adjust(p_difference: np.ndarray, p_equivalence: np.ndarray, method: str = "holm"
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Both p-value sets of one family adjusted in a single pass: every finite p (difference or
    equivalence, of any row) is one hypothesis of the family, so the family-wise error over all
    of them is at most ALPHA (Holm). NaN stays NaN and is not counted."""
    d, e = np.asarray(p_difference, dtype=float), np.asarray(p_equivalence, dtype=float)
    both = family_adjust(np.concatenate([d, e]), method)
    return both[: len(d)], both[len(d):]


def family_size(p_difference: np.ndarray, p_equivalence: np.ndarray) -> int:
    """How many hypotheses a family holds (finite p-values of either kind)."""
    return int(np.isfinite(np.asarray(p_difference, float)).sum() + np.isfinite(np.asarray(p_equivalence, float)).sum())


def holm_levels(p_difference: np.ndarray, p_equivalence: np.ndarray, alpha: float = ALPHA
                ) -> tuple[np.ndarray, np.ndarray, float]:
    """Where ``union_adjust``'s Holm procedure decided each hypothesis of one family: (the α of
    the step that rejected each difference hypothesis, the same for each equivalence hypothesis,
    the α of the step where Holm stopped). Step i of m tests at α/(m − i + 1); a hypothesis not
    rejected (adjusted p ≥ ``alpha``), or untested (NaN), gets NaN; the stop level is NaN when
    every hypothesis was rejected. A two-sided interval at confidence 1 − (its level) is the one
    dual to that decision: it excludes the null exactly when the test at that step rejects."""
    from scipy.stats import rankdata

    d, e = np.asarray(p_difference, dtype=float), np.asarray(p_equivalence, dtype=float)
    p = np.concatenate([d, e])
    adjusted = np.concatenate(union_adjust(d, e))
    ok = np.flatnonzero(np.isfinite(p))
    m = len(ok)
    levels = np.full_like(p, np.nan)
    rejected = adjusted[ok] < alpha
    step = rankdata(p[ok], method="ordinal")  # i: the step at which Holm met the hypothesis
    levels[ok[rejected]] = alpha / (m - step[rejected] + 1)
    stop = alpha / (m - int(rejected.sum())) if rejected.sum() < m else math.nan
    return levels[: len(d)], levels[len(d):], stop


def minimal_effect_p(d: np.ndarray, sesoi: float) -> float:
    """p that the mean of ``d`` lies outside ±sesoi (H0: |mean| ≤ sesoi): the smaller of the two
    one-sided t-tests against +sesoi (greater) and −sesoi (less), doubled (Bonferroni over sides)."""
    d = np.asarray(d, dtype=float)
    upper = stats.ttest_1samp(d, sesoi, alternative="greater").pvalue
    lower = stats.ttest_1samp(d, -sesoi, alternative="less").pvalue
    return float(min(1.0, 2 * min(upper, lower)))


def tost_paired(d: np.ndarray, sesoi: float) -> float:
    """p of the two one-sided tests that the mean paired difference lies within ±sesoi."""
    from statsmodels.stats.weightstats import ttost_paired

    d = np.asarray(d, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):  # identical differences (SD 0): t = ±inf, p 0 or 1
        return float(ttost_paired(d, np.zeros_like(d), -sesoi, sesoi)[0])


def tost_ind(a: np.ndarray, b: np.ndarray, sesoi: float) -> float:
    """p of the two one-sided Welch tests that mean(a) − mean(b) lies within ±sesoi."""
    from statsmodels.stats.weightstats import ttost_ind

    return float(ttost_ind(np.asarray(a, float), np.asarray(b, float), -sesoi, sesoi, usevar="unequal")[0])


def t_power(sesoi: float, sd: float, n: int, paired: bool, alpha: float = ALPHA) -> float:
    """Power of the two-sided paired/one-sample t (``paired``) or two-sample t with ``n`` pairs or
    runs per arm when the true effect is ``sesoi`` (statsmodels, at a whole ``n``)."""
    from statsmodels.stats.power import TTestIndPower, TTestPower

    solver = TTestPower() if paired else TTestIndPower()
    return float(solver.power(sesoi / sd, n, alpha, alternative="two-sided"))


def n_for_t(sesoi: float, sd: float, paired: bool, alpha: float = ALPHA) -> float:
    """Pairs (``paired``: one-sample/paired t) or runs per arm (Welch ≈ two-sample t) for 80%
    power of a two-sided test at ``alpha`` when the true effect is ``sesoi``; ``sd`` is the SD of
    the paired differences (or the pooled SD of the runs). inf when it exceeds N_MAX.

    A search over whole run counts with statsmodels' power: its ``solve_power`` root-finds over a
    continuous n, where scipy's noncentral t returns NaN at some non-integer n and the solver then
    stops early (it gave 6 pairs for ablation.gate_improves where 7 are needed; tests/harness)."""
    if not (sd > 0 and sesoi > 0):
        return math.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        def enough(n: int) -> bool:
            power = t_power(sesoi, sd, n, paired, alpha)
            # scipy's noncentral t also returns NaN far out in its tail, at large n·(sesoi/sd)²,
            # where the power is 1 to many digits
            return math.isnan(power) or power >= POWER

        return _smallest(enough, 1)  # power at 1 is below POWER (a t-test needs 2 runs an arm)


def levene_median_p(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Brown–Forsythe p-values of many experiments at once (rows of ``a`` against rows of ``b``):
    the one-way ANOVA of absolute deviations from each group's median, exactly what
    ``scipy.stats.levene(x, y, center="median")`` computes per pair (checked by the tests)."""
    za = np.abs(a - np.median(a, axis=1, keepdims=True))
    zb = np.abs(b - np.median(b, axis=1, keepdims=True))
    na, nb = a.shape[1], b.shape[1]
    ma, mb = za.mean(axis=1), zb.mean(axis=1)
    grand = (za.sum(axis=1) + zb.sum(axis=1)) / (na + nb)
    between = na * (ma - grand) ** 2 + nb * (mb - grand) ** 2
    within = ((za - ma[:, None]) ** 2).sum(axis=1) + ((zb - mb[:, None]) ** 2).sum(axis=1)
    f = between / (within / (na + nb - 2))
    return stats.f.sf(f, 1, na + nb - 2)


def bf_power(sd_ratio: float, n: int, draws: int = BF_DRAWS, seed: int = BF_SEED, alpha: float = ALPHA) -> float:
    """Power of the two-sided Brown–Forsythe test with ``n`` runs per arm when one arm's SD is
    ``sd_ratio`` times the other's (normal samples; ``draws`` simulated experiments, ``seed``)."""
    rng = np.random.default_rng(seed)
    a = rng.normal(0.0, sd_ratio, (draws, n))
    b = rng.normal(0.0, 1.0, (draws, n))
    return float((levene_median_p(a, b) < alpha).mean())


def n_for_bf(sd_ratio: float, draws: int = BF_DRAWS, seed: int = BF_SEED, n_max: int = 200) -> float:
    """Smallest n per arm with simulated Brown–Forsythe power ≥ 80% at ``sd_ratio`` (inf past ``n_max``)."""
    if not sd_ratio > 0 or sd_ratio == 1:
        return math.inf
    lo, hi = 2, 4
    while bf_power(sd_ratio, hi, draws, seed) < POWER:
        lo, hi = hi, hi * 2
        if hi > n_max:
            return math.inf
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if bf_power(sd_ratio, mid, draws, seed) >= POWER else (mid, hi)
    return float(hi)


def pitman_morgan(a: np.ndarray, b: np.ndarray, ratio: float = 1.0, alternative: str = "two-sided") -> float:
    """p of the Pitman–Morgan test that SD(a)/SD(b) = ``ratio`` for paired samples (a[i] with
    b[i]): var(a) − ratio²·var(b) = cov(a + ratio·b, a − ratio·b), so the hypothesis is a zero
    Pearson correlation of those two series (exact under bivariate normality, n − 2 df).
    ``alternative``: "less" (the true ratio is below ``ratio``), "greater", or "two-sided"."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    u, v = a + ratio * b, a - ratio * b
    if np.ptp(u) == 0 or np.ptp(v) == 0:
        return math.nan
    return float(stats.pearsonr(u, v, alternative=alternative).pvalue)


def pitman_morgan_tost(a: np.ndarray, b: np.ndarray, sesoi: float) -> float:
    """p that SD(a)/SD(b) lies within [1/sesoi, sesoi] (two one-sided Pitman–Morgan tests)."""
    below = pitman_morgan(a, b, sesoi, "less")  # rejects "ratio ≥ sesoi"
    above = pitman_morgan(a, b, 1.0 / sesoi, "greater")  # rejects "ratio ≤ 1/sesoi"
    return max(below, above)


def pm_power(sd_ratio: float, n: int, rho: float = 0.0, draws: int = BF_DRAWS, seed: int = BF_SEED,
             alpha: float = ALPHA) -> float:
    """Power of the two-sided Pitman–Morgan test with ``n`` pairs when SD(a) = ``sd_ratio``·SD(b)
    and the paired runs correlate ``rho`` (bivariate normal; ``draws`` experiments, ``seed``)."""
    rng = np.random.default_rng(seed)
    z1, z2 = rng.normal(size=(2, draws, n))
    b = z1
    a = sd_ratio * (rho * z1 + math.sqrt(1 - rho * rho) * z2)
    u, v = a + b, a - b
    u, v = u - u.mean(axis=1, keepdims=True), v - v.mean(axis=1, keepdims=True)
    r = (u * v).sum(axis=1) / np.sqrt((u * u).sum(axis=1) * (v * v).sum(axis=1))
    t = r * np.sqrt((n - 2) / np.maximum(1e-300, 1 - r * r))
    return float((2 * stats.t.sf(np.abs(t), n - 2) < alpha).mean())


def n_for_pm(sd_ratio: float, rho: float = 0.0, alpha: float = ALPHA, draws: int = BF_DRAWS, seed: int = BF_SEED,
             n_max: int = 200) -> float:
    """Smallest number of pairs with simulated Pitman–Morgan power ≥ 80% at ``sd_ratio`` (inf past ``n_max``)."""
    if not sd_ratio > 0 or sd_ratio == 1:
        return math.inf
    lo, hi = 3, 4
    while pm_power(sd_ratio, hi, rho, draws, seed, alpha) < POWER:
        lo, hi = hi, hi * 2
        if hi > n_max:
            return math.inf
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if pm_power(sd_ratio, mid, rho, draws, seed, alpha) >= POWER else (mid, hi)
    return float(hi)


def heterogeneity(groups: list[np.ndarray]) -> float:
    """p that the groups' means differ (one-way ANOVA); NaN with fewer than two usable groups."""
    groups = [np.asarray(g, float) for g in groups if len(g) >= 2]
    if len(groups) < 2:
        return math.nan
    return float(stats.f_oneway(*groups).pvalue)


@dataclass(frozen=True)
class PaperEvidence:
    """The paper's own difference against its own spread, for one dataset."""

    effect: float
    p: float  # Welch from the paper's summary statistics; NaN without a spread
    how: str  # which spread was used, or why none


def paper_evidence(a: float, b: float, a_std: float | None, b_std: float | None, n: int | None,
                   run_sd: float | None = None, run_sd_n: int | None = None) -> PaperEvidence:
    """``ttest_ind_from_stats`` (Welch) on the paper's a and b: with their own stds and n, else
    with the paper's run-to-run SD on that dataset for both arms, else no test."""
    effect = a - b
    if a_std is not None and b_std is not None and n:
        res = stats.ttest_ind_from_stats(a, a_std, n, b, b_std, n, equal_var=False)
        return PaperEvidence(effect, float(res.pvalue), f"its ± over {n} runs")
    if run_sd is not None and run_sd_n:
        res = stats.ttest_ind_from_stats(a, run_sd, run_sd_n, b, run_sd, run_sd_n, equal_var=False)
        return PaperEvidence(effect, float(res.pvalue), f"its run-to-run SD {run_sd:g} ({run_sd_n} runs) for both")
    return PaperEvidence(effect, math.nan, "no spread reported")


def iu_power(effects: tuple[float, float], n: int, alpha: float) -> float:
    """Lower bound on the power of an intersection–union test of two one-sided one-sample (paired)
    t-tests, each at ``alpha``, with ``n`` pairs, when the standardised effects (effect/SD) on
    their alternative side are ``effects``: p₁ + p₂ − 1 (Fréchet; exact when one test is
    certain to reject), whatever the correlation between the two statistics (statsmodels)."""
    from statsmodels.stats.power import TTestPower

    solver = TTestPower()
    p = [float(solver.power(d, n, alpha, alternative="larger")) for d in effects]
    return max(0.0, p[0] + p[1] - 1.0)


def n_for_iu(effects: tuple[float, float], alpha: float) -> float:
    """Pairs for ``iu_power`` ≥ 80%; NaN when an effect is not positive and finite, inf past N_MAX."""
    if not all(d > 0 and math.isfinite(d) for d in effects):
        return math.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        def enough(n: int) -> bool:
            power = iu_power(effects, n, alpha)
            return math.isnan(power) or power >= POWER

        return _smallest(enough, 2)  # the search needs 3 seeds a pair: 2 is taken as too few


def _smallest(enough: Callable[[int], bool], lo: int) -> float:
    """The smallest n in (lo, N_MAX] with ``enough(n)`` (monotone in n), by doubling then bisection;
    inf when N_MAX is not enough."""
    if not enough(N_MAX):
        return math.inf
    hi = lo + 1
    while not enough(hi):
        lo, hi = hi, min(2 * hi, N_MAX)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if enough(mid) else (mid, hi)
    return float(hi)
