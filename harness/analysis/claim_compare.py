"""Which test a claim gets (``compare``) and a pooled claim's split by scene (``scene_split``).

The dispatcher over ``claim_tests``' primitives, the existential searches (``existential``) and
the instance-level tests (``instance_unit``), kept apart from all three because each of them
imports ``claim_tests`` (one module calling them from there would be an import cycle).
"""

from __future__ import annotations

import math

import pandas as pd

from harness.analysis import claim_tests as C, existential, instance_unit, stats
from harness.analysis.claim_tests import Result
from harness.spec.instances import takes_instances, tested
from harness.spec.study_schema import ClaimSpec


def compare(df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> Result:
    """The claim's test on the FINISHED runs of ``df`` on ``scenes``; ValueError when too few runs.
    A mean, contrast or interaction claim whose runs include fresh instances of a scene takes the
    instance as its unit, the pilot instance 0 left out (``instance_unit``); any other claim
    reads the scenes as written (instance 0) only (``spec.instances.tested``)."""
    df = df if takes_instances(claim) else tested(df, claim)  # the seed its unit: the scenes as written
    if instance_unit.by_instance(df, claim, scenes):
        waiting, drawn = instance_unit.pending(df, claim, scenes)
        if waiting:
            raise ValueError(f"{drawn - waiting} of the {drawn} runs of its arms on fresh instances have run: the"
                             " instance-level test reads every drawn instance, so it waits for the rest")
        if claim.test == "mean":
            return instance_unit.claim_test(df, claim, scenes)
        res = compare(instance_unit.units(df, claim, scenes), claim, scenes)  # no instance columns: by seed
        res.method = res.method.replace("per-seed", "per-instance") + ", over instance means"
        res.n = res.n.replace("runs", "instances").replace("pairs", "instances")
        res.n += "" if "instances" in res.n else " instances"
        return res
    if claim.test == "contrast":
        return C.contrast(df, claim, scenes)
    if claim.test == "decoupled":
        return existential.decoupled(df, claim, scenes)
    if claim.test == "dissociated":
        return existential.dissociated(df, claim, scenes)
    if claim.test == "spread":
        return C.spread(df, claim, scenes)
    if claim.test == "interaction":
        pairs = claim.pairs or ((claim.a, claim.b),) * len(claim.scenes)
        d1, d2 = (C.pair_differences(df, claim.metric, a, b, (s,)).to_numpy(dtype=float)
                  for s, (a, b) in zip(claim.scenes, pairs))
        if min(len(d1), len(d2)) < 2:
            raise ValueError(f"{len(d1)} and {len(d2)} pairs on the two scenes (need 2 each)")
        res = C.compare_means(d1, d2, paired=False, sesoi=claim.sesoi)
        res.method = "Welch t on per-seed differences (difference of differences)"
        return res
    if claim.test == "mean" and claim.b and claim.pair == "seed":
        d = C.paired_differences(df, claim, scenes)
        if len(d) < 2:
            raise ValueError(f"{len(d)} (scene, seed) pairs where both variants finished (need 2)")
        res = C.compare_means(d.to_numpy(dtype=float), None, True, claim.sesoi)
        res.method, res.n = "paired t (by scene and seed)", f"{len(d)} pairs"
        return res
    ok = C.finished(df, claim.metric, scenes)
    if claim.test == "variance":  # centred per cell: pooling scenes adds no between-scene spread
        centre = ok.groupby(["variant", "scene"])[claim.metric].transform("mean")
        ok = ok.assign(**{claim.metric: ok[claim.metric] - centre})
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
            return C.compare_variances(w[claim.a].to_numpy(float), w[claim.b].to_numpy(float), claim.sesoi,
                                     names=(claim.a, claim.b), paired=True)
        return C.compare_variances(a, b, claim.sesoi, names=(claim.a, claim.b))
    return C.compare_means(a, b, paired=False, sesoi=claim.sesoi)


def scene_split(df: pd.DataFrame, claim: ClaimSpec) -> tuple[float, dict[str, float]]:
    """(heterogeneity p, per-scene mean effect) of a paired claim pooled over several scenes: the
    scenes as the study file writes them, each over its instances (per-instance means for a claim
    with the instance as its unit, ``instance_unit.by_instance``, the pilot left out)."""
    if claim.test not in ("mean", "contrast") or not claim.b or claim.pair != "seed" or len(claim.scenes) == 1:
        return math.nan, {}
    df = df if takes_instances(claim) else tested(df, claim)
    several = instance_unit.by_instance(df, claim, claim.scenes)
    d = C.paired_differences(instance_unit.units(df, claim, claim.scenes) if several else df, claim, claim.scenes)
    if d.empty:
        return math.nan, {}
    base = dict(zip(df.scene, df.instance_of)) if "instance_of" in df else {}
    scenes = pd.Index(d.index.get_level_values("scene")).map(lambda s: base.get(s, s))
    order = [s for s in (claim.scenes or tuple(dict.fromkeys(scenes))) if s in set(scenes)]
    by_scene = {s: d[scenes == s].to_numpy(dtype=float) for s in order}
    return stats.heterogeneity(list(by_scene.values())), {s: float(v.mean()) for s, v in by_scene.items()}
