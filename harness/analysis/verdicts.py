"""From tested claims to verdicts a referee would accept.

``evaluate(df, claims)`` tests every claim of a study on its runs (``analysis.claim_tests``): one
row per hypothesis (a claim, or one scene of a scene-dependent claim) with the raw p of the
difference test and of the equivalence test, the heterogeneity p, the paper's numbers and
the paper's own evidence. ``decide(frame)`` corrects the p-values over each named family
(``ClaimSpec.group``: Holm by default, separately for the difference and the equivalence
tests) and gives every row one verdict:

- **equivalent**: the equivalence test rejects (the effect is within ±SESOI): no effect as
  large as the one of interest at this scale — a decision, not a shrug;
- **reproduced** / **contradicted**: the difference test rejects, the effect in the claimed /
  the opposite direction (``not_higher`` / ``not_lower`` claims are also reproduced by
  equivalence; ``exists`` claims by their existential test);
- **inconclusive**: neither, with the runs per arm that 80% power at the SESOI needs;
- **not tested** (the runs it needs are missing) and **not exercised** (the mechanism it
  needs is absent on the scene: ``ClaimSpec.requires``) are not in any family.

The study report calls ``decide`` on one study's rows (labelled "within this study");
``reports/index.md`` calls it on every study's rows at once (the family the tally is over).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from harness.analysis import claim_tests as C, stats
from harness.spec.study_schema import ClaimSpec

REPRODUCED, CONTRADICTED, EQUIVALENT, INCONCLUSIVE = "reproduced", "contradicted", "equivalent", "inconclusive"
NOT_TESTED, NOT_EXERCISED = "not tested", "not exercised"
CORRECTION = "holm"
COLUMNS = ["id", "group", "statement", "metric", "test", "expect", "comparison", "scene", "scope", "method", "n",
           "effect", "ci_low", "ci_high", "ci90_low", "ci90_high", "sesoi", "sesoi_source", "stat_name", "statistic",
           "p", "p_tost", "p_het", "p_adj", "p_tost_adj", "family", "verdict", "n_needed", "note", "detail",
           "paper_statement", "paper_source", "paper_numbers", "paper_evidence", "paper_effects"]


def comparison_text(claim: ClaimSpec) -> str:
    """What is compared, in words: ``cc − baseline (studio)``."""
    where = f" ({', '.join(claim.scenes)})" if claim.scenes and claim.test != "interaction" else ""
    if claim.test == "decoupled":
        return f"some pair equal in {claim.metric} (±{claim.sesoi:g}) but not in {claim.versus}{where}"
    if claim.test == "variance":
        return f"SD {claim.a} / SD {claim.b}{where}"
    if claim.test == "interaction":
        return f"({claim.a} − {claim.b}) on {claim.scenes[0]} − on {claim.scenes[1]}"
    if claim.test == "contrast":
        return " and ".join(" ".join(f"{k:+g}·{v}" for v, k in w) for w in claim.contrasts) + where
    return f"{claim.a} − {claim.b or '0'}{where}"


def _paper_columns(claim: ClaimSpec) -> dict[str, str]:
    """The paper's numbers, its own evidence per dataset and its effects (for the forest plot)."""
    if claim.paper is None:
        return {"paper_statement": "", "paper_source": "", "paper_numbers": "", "paper_evidence": "",
                "paper_effects": ""}
    numbers, evidence, effects = [], [], []
    for r in claim.paper.rows:
        if claim.test == "variance" and r.a_std is not None and r.b_std is not None:
            numbers.append(f"{r.dataset}: SD {r.b_std:g} → {r.a_std:g} ({r.n} runs)")
            effects.append(f"{r.dataset}={r.a_std / r.b_std:.6g}")
            evidence.append(f"{r.dataset}: {_f_test(r.a_std, r.b_std, r.n)}")
            continue
        if r.a is None:
            numbers.append(f"{r.dataset}: {r.note or 'no number'}")
            continue
        pm = (lambda v, sd: f"{v:g} ± {sd:g}" if sd is not None else f"{v:g}")
        numbers.append(f"{r.dataset}: {pm(r.b, r.b_std)} → {pm(r.a, r.a_std)}" + (f" ({r.n} runs)" if r.n else "")
                       if r.b is not None else f"{r.dataset}: {r.a:+g}")
        effects.append(f"{r.dataset}={r.effect:.6g}")
        if r.b is not None:
            ev = stats.paper_evidence(r.a, r.b, r.a_std, r.b_std, r.n, r.run_sd, r.run_sd_n)
            evidence.append(f"{r.dataset}: {ev.effect:+.2f}, " + (
                "no spread reported" if math.isnan(ev.p) else
                f"p = {ev.p:.2g} ({ev.how}): {'distinguishable' if ev.p < stats.ALPHA else 'not distinguishable'}"
                " from its own spread"))
    return {"paper_statement": claim.paper.statement, "paper_source": claim.paper.source,
            "paper_numbers": "; ".join(numbers), "paper_evidence": "; ".join(evidence),
            "paper_effects": ";".join(effects)}


def _f_test(a_std: float, b_std: float, n: int | None) -> str:
    """The paper's SD ratio against chance for its n (a two-sided F-test on its SDs)."""
    if not n:
        return "no run count reported"
    from scipy import stats as sps

    f = (a_std / b_std) ** 2
    p = 2 * min(sps.f.cdf(f, n - 1, n - 1), sps.f.sf(f, n - 1, n - 1))
    return f"SD ratio {a_std / b_std:.2f}, F-test p = {p:.2g} ({'distinguishable' if p < stats.ALPHA else 'not distinguishable'})"


def _row(claim: ClaimSpec, scene: str, scope: str) -> dict:
    return {"id": claim.id if not scene else f"{claim.id}[{scene}]", "group": claim.group,
            "statement": claim.statement, "metric": claim.metric, "test": claim.test, "expect": claim.expect,
            "comparison": comparison_text(claim), "scene": scene, "scope": scope, "method": "", "n": "",
            "effect": math.nan, "ci_low": math.nan, "ci_high": math.nan, "ci90_low": math.nan, "ci90_high": math.nan,
            "sesoi": claim.sesoi, "sesoi_source": claim.sesoi_source, "stat_name": "", "statistic": math.nan,
            "p": math.nan, "p_tost": math.nan, "p_het": math.nan, "p_adj": math.nan, "p_tost_adj": math.nan,
            "family": "", "verdict": NOT_TESTED, "n_needed": math.nan, "note": "", "detail": "",
            **_paper_columns(claim)}


def _tested(row: dict, df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> dict:
    absent = C.not_exercised(df, claim, scenes)
    if absent:
        return {**row, "verdict": NOT_EXERCISED, "note": absent}
    try:
        res = C.compare(df, claim, scenes)
    except ValueError as err:
        return {**row, "note": str(err)}
    row = {**row, "method": res.method, "n": res.n, "effect": res.effect, "ci_low": res.ci[0], "ci_high": res.ci[1],
           "ci90_low": res.ci90[0], "ci90_high": res.ci90[1], "stat_name": res.stat_name,
           "statistic": res.statistic, "p": res.p, "p_tost": res.p_tost, "detail": res.detail,
           "verdict": INCONCLUSIVE, "n_needed": res.needed()}
    if not np.isfinite(res.p):
        row.update(verdict=NOT_TESTED, note="no spread in the data: the test is undefined")
    return row


def evaluate(df: pd.DataFrame, claims: tuple[ClaimSpec, ...] | list[ClaimSpec]) -> pd.DataFrame:
    """One row per hypothesis (``COLUMNS``) with raw p-values; verdicts need ``decide``."""
    rows = []
    for c in claims:
        why = C.missing(df, c)
        if why:
            rows.append({**_row(c, "", "pooled" if len(c.scenes) != 1 else c.scenes[0]), "note": why})
            continue
        p_het, per_scene = C.scene_split(df, c)
        signs = {np.sign(v) for v in per_scene.values() if v != 0}
        if p_het < stats.ALPHA and len(signs) > 1:  # the scenes disagree: never pooled over opposite signs
            for scene in per_scene:
                row = _row(c, scene, f"scene-dependent (heterogeneity p = {p_het:.2g})")
                rows.append({**_tested(row, df, c, (scene,)), "p_het": p_het})
            continue
        used = list(c.scenes) or list(dict.fromkeys(C.finished(df, c.metric).scene))
        scope = ", ".join(used) + (" (pooled)" if len(used) > 1 and c.test != "interaction" else "")
        rows.append({**_tested(_row(c, "", scope), df, c, c.scenes), "p_het": p_het})
    return pd.DataFrame(rows, columns=COLUMNS)


def _direction(effect: float, test: str) -> int:
    """+1 when a is higher than b (a ratio above 1 for variance claims), -1 when lower."""
    centre = 1.0 if test == "variance" else 0.0
    return 0 if not np.isfinite(effect) or effect == centre else (1 if effect > centre else -1)


def verdict(expect: str, effect: float, test: str, p_adj: float, p_tost_adj: float, alpha: float = stats.ALPHA) -> str:
    """The verdict of one hypothesis from its family-corrected p-values (module docstring)."""
    if expect == "exists":
        return REPRODUCED if p_adj < alpha else INCONCLUSIVE
    sign = _direction(effect, test)
    equivalent = p_tost_adj < alpha
    different = p_adj < alpha and sign != 0
    if expect in ("not_higher", "not_lower"):
        against = 1 if expect == "not_higher" else -1
        if equivalent:  # within ±SESOI: not higher (or lower) by an amount of interest
            return REPRODUCED
        if different:
            return CONTRADICTED if sign == against else REPRODUCED
        return INCONCLUSIVE
    if equivalent:
        return EQUIVALENT
    if different:
        return REPRODUCED if sign == (1 if expect == "higher" else -1) else CONTRADICTED
    return INCONCLUSIVE


def decide(frame: pd.DataFrame, method: str = CORRECTION, label: str = "") -> pd.DataFrame:
    """``frame`` with ``p_adj``, ``p_tost_adj``, ``family`` and ``verdict`` per row: each group
    is one family, corrected with ``method`` separately for difference and equivalence p-values."""
    out = frame.copy()
    tested = out.verdict.isin([INCONCLUSIVE, REPRODUCED, CONTRADICTED, EQUIVALENT])
    for group, idx in out[tested].groupby("group").groups.items():
        n = len(idx)
        out.loc[idx, "p_adj"] = stats.family_adjust(out.loc[idx, "p"].to_numpy(float), method)
        out.loc[idx, "p_tost_adj"] = stats.family_adjust(out.loc[idx, "p_tost"].to_numpy(float), method)
        out.loc[idx, "family"] = f"{group}{label}: {method.capitalize()} over {n}"
    for i in out[tested].index:
        r = out.loc[i]
        v = verdict(r.expect, float(r.effect), r.test, float(r.p_adj), float(r.p_tost_adj))
        out.at[i, "verdict"] = v
        if v != INCONCLUSIVE:
            out.at[i, "n_needed"] = math.nan
    return out


def in_sesoi_units(row: pd.Series) -> tuple[float, float, float]:
    """(effect, ci low, ci high) divided by the SESOI (log scale for SD ratios): ±1 is the band
    of no interest, the forest plot's axis."""
    if row.test == "variance":
        scale = math.log(row.sesoi)
        return tuple(math.log(v) / scale if v > 0 else math.nan for v in (row.effect, row.ci_low, row.ci_high))
    return row.effect / row.sesoi, row.ci_low / row.sesoi, row.ci_high / row.sesoi
