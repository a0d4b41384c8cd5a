"""Existential claims: "some pair of variants, on some scene, ..." (``claim_compare.compare`` calls these).

- ``decoupled``: on some scene, a pair of variants equivalent in ``metric`` within ±SESOI
  (TOST) whose ``versus`` differs (paired t); p per pair = the larger of the two, Bonferroni
  over the pairs tried.
- ``dissociated``: on some scene, an ordered pair (x, y): x not worse than y in ``metric`` by
  the SESOI (one-sided t) yet worse in ``versus`` (one-sided paired t); p per pair = the larger,
  Bonferroni over every ordered pair tried. Its power (``IUPower``) is the intersection–union
  bound of ``stats.iu_power`` at the best pair's SDs: equal rendering against the −SESOI margin,
  and ``versus`` worse by that metric's own SESOI (``spec.metrics.sesoi``), each at α/pairs.

Both search every pair of the study's variants (``claim.among`` when it names some) with at
least 3 seeds that logged both metrics, paired by seed on one scene (all instances of a scene
written in the study file, ``spec.instances``, are its cells).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats as sps

from harness.analysis import stats
from harness.analysis.claim_tests import CONFIDENCE, Result, t_ci, t_interval, wide
from harness.spec.study_schema import ClaimSpec


@dataclass(frozen=True)
class IUPower:
    """What a dissociated claim's runs-needed figure reads (``verdicts`` row ``power_param``):
    the two one-sided tests' standardised effects of interest and the ordered pairs tried."""

    effects: tuple[float, float]  # (SESOI of the metric / SD of its differences, SESOI of versus / its SD)
    pairs: int

    def needed(self, alpha: float) -> float:
        """Seeds a pair needs for 80% power when the claim holds ``alpha`` (Bonferroni over the pairs)."""
        return stats.n_for_iu(self.effects, alpha / self.pairs)

    def __str__(self) -> str:
        return f"d {self.effects[0]:.3g} and {self.effects[1]:.3g}, {self.pairs} pairs"


def seed_aligned(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...], pairs: Callable
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


def decoupled(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
    tried = []
    for scene, va, vb, x, y in seed_aligned(df, claim, scenes, itertools.combinations):
        p_equal = stats.tost_paired((x[va] - x[vb]).to_numpy(float), claim.sesoi)
        dy = (y[va] - y[vb]).to_numpy(float)
        differs = sps.ttest_1samp(dy, 0.0)
        tried.append((max(p_equal, float(differs.pvalue)), scene, va, vb, dy, differs, p_equal))
    if not tried:
        raise ValueError("no scene with 3 seeds of two variants that logged both metrics")
    p, scene, va, vb, dy, res, p_equal = min(tried, key=lambda t: t[0])
    return Result(f"existential: per scene and variant pair, TOST of {claim.metric} within ±{claim.sesoi:g} and"
                  f" paired t of {claim.versus}; p = max of the two, Bonferroni over {len(tried)} pairs",
                  f"{len(dy)} pairs", float(dy.mean()), t_ci(res, CONFIDENCE), t_ci(res, 0.90), "t",
                  float(res.statistic), min(1.0, p * len(tried)), math.nan, ("", math.nan),
                  f"best pair {va} vs {vb} on {scene}: {claim.metric} equivalent (TOST p = {p_equal:.2g}),"
                  f" {claim.versus} differs by {dy.mean():+.3g} (p = {res.pvalue:.2g})", interval=t_interval(res))


def dissociated(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
    """On some scene, an ordered pair (x, y): x is not worse than y in ``metric`` by the SESOI
    (one-sided t against −SESOI on the better side) yet worse in ``versus`` (one-sided paired t);
    p per pair = the larger of the two, Bonferroni over every ordered pair tried."""
    from harness.spec.metrics import lower_is_better, sesoi

    sign_m = -1.0 if lower_is_better(claim.metric) else 1.0  # turns "better" into "higher"
    sign_v = -1.0 if lower_is_better(claim.versus) else 1.0
    tried = []
    for scene, vx, vy, x, y in seed_aligned(df, claim, scenes, itertools.permutations):
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
    power = IUPower((claim.sesoi / _sd(dm), sesoi(claim.versus)[0] / _sd(dv)), len(tried))
    return Result(f"existential: per scene and ordered variant pair, {claim.metric} not worse by ±{claim.sesoi:g}"
                  f" (one-sided t) and {claim.versus} worse (one-sided paired t); p = the larger, Bonferroni over"
                  f" {len(tried)} pairs", f"{len(dv)} pairs", float(raw.mean()), t_ci(res, CONFIDENCE),
                  t_ci(res, 0.90), "t", float(res.statistic), min(1.0, p * len(tried)), math.nan, ("iu", power),
                  f"best pair {vx} vs {vy} on {scene}: {claim.metric} {sign_m * dm.mean():+.3g} (not worse by"
                  f" {claim.sesoi:g}: p = {p_not_worse:.2g}), {claim.versus} {raw.mean():+.3g} (worse)",
                  interval=t_interval(res))


def _sd(x: object) -> float:
    """Sample SD (NaN when it is zero: no spread, no power figure)."""
    sd = float(np.std(np.asarray(x, float), ddof=1))
    return sd if sd > 0 else math.nan
