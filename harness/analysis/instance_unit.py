"""Scene instances as the unit of a claim about a kind of scene (issue 57; docs/sequential.md).

Seeds on one scene instance are technical replicates (pseudo-replication, Hurlbert 1984): when
a method's effect varies from instance to instance, a test that counts every (instance, seed)
pair as a unit reads that variation as noise it has averaged away, and rejects a true null far
more often than α (tests/harness/test_sequential.py measures it). A claim about a method *on a
kind of scene* therefore takes the instance as its unit:

- ``instance_test``: each variant's mean per (scene, instance) over its seeds, then the claim's
  own test (``claim_tests.compare_means``: paired by instance, Welch, or one-sample) on those
  means — exact under normal instance means, whatever the seeds' spread;
- ``mixed_model_test``: statsmodels' ``MixedLM`` on the runs themselves, the instance a random
  effect on the intercept and on the variant's effect (REML), its Wald statistic read against t
  with (instances − 1) degrees of freedom (statsmodels gives z, which over a handful of instances
  rejects too often); on a balanced design it equals the instance-means test, and it uses
  unbalanced seeds per instance as they are.

A run-to-run claim (one fixed scene, the paper's secret 5) keeps the seed as its unit. The runs
frame has the columns ``variant``, ``scene``, ``instance``, ``seed`` and the metric.

A study's claims (``claim_compare.compare``) use it through ``claim_test`` and ``units``: a mean,
contrast or interaction claim (``spec.instances.takes_instances``: not ``unit: seed``) whose runs
include a fresh instance (1, 2, …) of one of its scenes (``by_instance``; the study's runs frame
names each run's scene as written, ``instance_of``, and its ``instance``) is tested with the
(instance_of, instance) as its unit on the fresh instances only: instance 0, the scene as
written, is every claim's pilot and is left out (``spec.instances.tested``). Without a fresh
instance it keeps today's test over seeds. ``unit_text`` is what a verdict row says its unit is.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import pandas as pd
from scipy import stats as sps

from harness.analysis import claim_tests
from harness.spec.instances import PILOT, on_scenes, takes_instances, tested
from harness.spec.study_schema import ClaimSpec, Pairing, plural

UNIT = ["scene", "instance"]


def instance_means(df: pd.DataFrame, metric: str) -> pd.DataFrame:
    """One row per (variant, scene, instance): the mean of ``metric`` over its seeds and how many
    seeds it has (``runs``)."""
    return (df.dropna(subset=[metric]).groupby(["variant", *UNIT], sort=True)[metric]
            .agg([("value", "mean"), ("runs", "size")]).reset_index().rename(columns={"value": metric}))


def instance_test(df: pd.DataFrame, metric: str, a: str, b: str | None, sesoi: float,
                  paired: bool = True) -> claim_tests.Result:
    """``a`` − ``b`` with the (scene, instance) as the unit: per-instance means, then the paired t
    over instances both variants ran on (``paired``), Welch between the two sets of instances, or
    a one-sample t of ``a``'s instance means (``b`` None). ValueError under 2 instances."""
    means = instance_means(df, metric)
    table = means.set_index(["variant", *UNIT])[metric].unstack("variant")
    arms = [a] if b is None else [a, b]
    if not set(arms) <= set(table.columns):
        raise ValueError(f"no instance of {' and '.join(arms)} has `{metric}`")
    if b is None or paired:
        both = table[arms].dropna()
        if len(both) < 2:
            raise ValueError(f"{len(both)} instances where {' and '.join(arms)} ran (need 2)")
        res = claim_tests.compare_means(both[a].to_numpy(float), None if b is None else both[b].to_numpy(float),
                                        True, sesoi)
        res.method = "one-sample t over instance means" if b is None else "paired t over instance means"
        res.n = f"{len(both)} instances"
        return res
    xa, xb = (table[v].dropna().to_numpy(float) for v in arms)
    if min(len(xa), len(xb)) < 2:
        raise ValueError(f"{len(xa)} vs {len(xb)} instances (need 2 each)")
    res = claim_tests.compare_means(xa, xb, False, sesoi)
    res.method, res.n = "Welch t over instance means", f"{len(xa)} vs {len(xb)} instances"
    return res


@dataclass(frozen=True)
class MixedResult:
    """The variant effect of a mixed model with the instance as a random effect."""

    effect: float  # a − b, the fixed effect
    se: float
    p: float  # two-sided, t with ``dof`` degrees of freedom
    dof: int  # instances − 1
    instances: int
    converged: bool
    note: str = ""  # statsmodels' warnings, when it gave any


def mixed_model_test(df: pd.DataFrame, metric: str, a: str, b: str) -> MixedResult:
    """``metric ~ is_a`` on the runs of ``a`` and ``b``, random intercept and random ``is_a``
    slope per (scene, instance), REML (``statsmodels.formula.api.mixedlm``); the Wald t of the
    fixed effect against t with instances − 1 degrees of freedom."""
    import statsmodels.formula.api as smf

    runs = df[df.variant.isin([a, b])].dropna(subset=[metric])
    data = pd.DataFrame({"y": runs[metric].to_numpy(float), "is_a": (runs.variant == a).to_numpy(float),
                         "unit": (runs.scene.astype(str) + "/" + runs.instance.astype(str)).to_numpy()})
    k = data.unit.nunique()
    if k < 2:
        raise ValueError(f"{k} instances (need 2)")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fit = smf.mixedlm("y ~ is_a", data, groups=data.unit, re_formula="~is_a").fit(reml=True)
    effect, se = float(fit.fe_params["is_a"]), float(fit.bse_fe["is_a"])
    t = effect / se if se > 0 else math.copysign(math.inf, effect)
    note = "; ".join(sorted({str(w.message).splitlines()[0] for w in caught}))
    return MixedResult(effect, se, float(2 * sps.t.sf(abs(t), k - 1)), k - 1, k, bool(fit.converged), note)


def seed_unit_p(df: pd.DataFrame, metric: str, a: str, b: str) -> float:
    """The pseudo-replicated test, for contrast: the paired t over every (scene, instance, seed)
    pair, as if each seed were an independent unit."""
    table = df.groupby(["variant", *UNIT, "seed"])[metric].first().unstack("variant")[[a, b]].dropna()
    return float(sps.ttest_1samp(table[a].to_numpy(float) - table[b].to_numpy(float), 0.0).pvalue)


# --------------------------------------------------------------------------- a study's claims


def claim_runs(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> pd.DataFrame:
    """The FINISHED runs of the claim's arms on ``scenes`` that logged its metric, with
    ``instance_of`` and ``instance`` (a frame without them: each scene is instance 0 of itself)."""
    runs = claim_tests.finished(df, claim.metric, scenes)
    if claim.arms():
        runs = runs[runs.variant.isin(claim.arms())]
    if "instance_of" not in runs:
        runs = runs.assign(instance_of=runs.scene, instance=0)
    return runs


def tested_runs(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> pd.DataFrame:
    """``claim_runs`` as the claim's test reads them (``spec.instances.tested``, decided on every
    row of ``df``, planned ones too: a drawn scene's pilot is left out before its fresh runs end)."""
    return claim_runs(tested(df, claim), claim, scenes)


def instances_spanned(runs: pd.DataFrame) -> pd.Series:
    """Distinct instances per scene as written (index ``instance_of``) among ``runs``."""
    if runs.empty:
        return pd.Series(dtype=int)
    return runs.groupby("instance_of", sort=False)["instance"].nunique()


def pending(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> tuple[int, int]:
    """(planned runs of the claim's arms on the fresh instances of its scenes that have not run
    yet — MISSING or RUNNING; a FAILED run has run and drops out —, all of them): a test with the
    instance as its unit reads every drawn instance, so it waits for the last one rather than
    take whichever have finished (its n is the count registered, not the count so far)."""
    if "instance" not in df or "status" not in df:
        return 0, 0
    rows = df[on_scenes(df, scenes) & (df.instance > PILOT)]
    rows = rows[rows.variant.isin(claim.arms())] if claim.arms() else rows
    return int(rows.status.isin(["MISSING", "RUNNING"]).sum()), len(rows)


def by_instance(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> bool:
    """Is ``claim`` tested with the instance as its unit? A mean, contrast or interaction claim
    (not ``unit: seed``) one of whose scenes has fresh instances in ``df`` (planned or run)."""
    if not takes_instances(claim) or "instance" not in df:
        return False
    return bool((df[on_scenes(df, scenes)].instance > PILOT).any())  # drawn, run or not


def units(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> pd.DataFrame:
    """The claim's tested runs as one row per (variant, scene as written, instance): each
    instance's mean of the metric over its seeds, its instance number in the ``seed`` column and
    no instance columns, so that a test pairing runs by (scene, seed) pairs them by instance (a
    contrast, an interaction) and reads every row."""
    runs = tested_runs(df, claim, scenes)
    out = runs.groupby(["variant", "instance_of", "instance"], sort=True)[claim.metric].mean().reset_index()
    return out.rename(columns={"instance_of": "scene", "instance": "seed"}).assign(status="FINISHED")


def claim_test(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> claim_tests.Result:
    """The claim's own test (paired by instance for ``pair: seed``, Welch for ``pair: none``,
    one-sample without ``b``) on per-(instance_of, instance) means over seeds (``instance_test``),
    the pilot instances left out."""
    runs = tested_runs(df, claim, scenes)
    return instance_test(runs.assign(scene=runs.instance_of), claim.metric, claim.a, claim.b or None, claim.sesoi,
                         paired=claim.pair == Pairing.seed)


def unit_text(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> str:
    """What the claim's test counts as a unit on these runs: ``3 instances`` (per-instance means;
    ``6 instances of 2 scenes``; ``, pilot left out`` when instance 0 ran too), else seeds: ``seeds
    of 1 instance``, ``seeds of 1 instance of each of 2 scenes``, ``seeds of 4 instances`` (a
    run-to-run claim over several instances)."""
    ran = claim_runs(df, claim, scenes)
    if by_instance(df, claim, scenes):
        spanned = instances_spanned(tested_runs(df, claim, scenes))
        k, n = int(spanned.sum()), len(spanned)
        pilot = ", pilot instance 0 left out" if (ran.instance == PILOT).any() else ""
        return plural(k, "instance") + (f" of {n} scenes" if n > 1 else "") + pilot
    spanned = instances_spanned(tested_runs(df, claim, scenes))
    k, n = int(spanned.sum()), len(spanned)
    if not k:
        return ""
    of_scenes = f" of {n} scenes" if n > 1 else ""
    if (spanned == 1).all():
        return "seeds of 1 instance" + (f" of each of {n} scenes" if n > 1 else "")
    return f"seeds of {plural(k, 'instance')}{of_scenes}"
