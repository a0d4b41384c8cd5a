"""From tested claims to verdicts a referee would accept.

``evaluate(df, claims, study, register)`` tests every claim of a study on its runs
(``analysis.claim_tests``): one row per hypothesis (a claim, or one scene of a scene-dependent
claim) with the raw p of the difference test, of the equivalence test and — for "≈" claims —
of the minimal-effect test, the heterogeneity p, and the claim's place in the paper register
(``spec.paper_register``: the claim that ``decides`` a statement, ``evidence`` shown inside a
statement's row, or a ``replaced`` claim), and the unit its test counted (``unit``: ``3 instances``
or ``seeds of 1 instance``, ``analysis.instance_unit``). ``decide(frame)`` corrects the rows that
count over each named family (``ClaimSpec.group``) and gives every row one verdict:

- **one family, one error rate**: every hypothesis a family can reject — difference and
  equivalence tests of every counted row — goes into one Holm procedure
  (``stats.union_adjust``), so the family-wise error is at most α (two separate Holm runs allow
  up to 2α; tests/harness/test_claims.py simulates it);
- **what counts**: extension and convention claims, and in the paper family exactly one row
  per statement (its deciding claim); evidence rows, withdrawn claims and descriptions are shown
  with their raw p and do not enter any family;
- **equivalent**: the equivalence test rejects (the effect is within ±SESOI): no effect as large
  as the one of interest at this scale — a decision, not a shrug;
- **reproduced** / **contradicted**: the difference test rejects, the effect in the claimed /
  the opposite direction (``not_higher`` / ``not_lower`` claims are also reproduced by
  equivalence; ``exists`` claims by their existential test; ``equivalent`` claims — the
  paper's "≈" — are reproduced by equivalence and contradicted by the minimal-effect test);
- **inconclusive**: neither, with the runs per arm that 80% power at the SESOI needs *at the α
  the claim faces* (Bonferroni's α/m of its family, the strictest step of Holm);
- **not tested** (the runs it needs are missing), **not exercised** (the mechanism it needs is
  absent on the scene: ``ClaimSpec.requires``), **described** (a spread described, no test),
  **evidence** and **withdrawn** are in no family.

Beside the direction, each deciding row judges the paper's *size* (``paper_size``): is the
paper's own effect inside our 95% CI ("as large as the paper's"), or is ours smaller or larger
along the paper's direction — or in the opposite direction.

Each decided row carries the interval its verdict used (``ci_adj_*``): at the confidence of the
Holm step that decided it (``adjusted_level``), so that it excludes 0 (or lies inside ±SESOI)
exactly when the test rejects; ``interval_note`` says when it lies wholly beyond the SESOI, even
for an inconclusive row. A counted row whose claim was not registered before its runs
(``registered_before_runs``, computed from git by ``spec.registration`` in ``report.families``)
is **exploratory**: it keeps its place in the family and its verdict, named so beside it.

The study report and ``reports/index.md`` both show the verdicts of one decision over every
study's rows (``report.families``), so a page and the index cannot disagree.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from harness.analysis import claim_compare, claim_tests as C, instance_unit, stats
from harness.analysis.paper_side import paper_columns, size_text  # re-exported: V.size_text
from harness.spec.paper_register import Register
from harness.spec.study_schema import ClaimSpec

REPRODUCED, CONTRADICTED, EQUIVALENT, INCONCLUSIVE = "reproduced", "contradicted", "equivalent", "inconclusive"
NOT_TESTED, NOT_EXERCISED, DESCRIBED = "not tested", "not exercised", "described"
EVIDENCE, WITHDRAWN = "evidence", "withdrawn"
DECIDED = (REPRODUCED, CONTRADICTED, EQUIVALENT, INCONCLUSIVE)  # verdicts of rows a family decides
CORRECTION = "holm"
DECIDES, AS_EVIDENCE, REPLACED = "decides", "evidence", "replaced"
COLUMNS = ["id", "claim", "group", "statement", "metric", "test", "expect", "comparison", "scene", "scope", "method",
           "n", "unit", "effect", "ci_low", "ci_high", "ci90_low", "ci90_high", "ci_adj_low", "ci_adj_high",
           "ci_adj_level", "sesoi", "sesoi_source", "stat_name", "statistic", "p", "p_tost", "p_outside", "p_het",
           "p_adj", "p_tost_adj", "family", "family_size", "verdict", "exploratory", "interval_note", "raw_verdict",
           "n_needed", "power_test", "power_param", "note", "detail", "role", "statement_id", "registered_commit",
           "role_commit", "first_run_commit", "registered_before_runs", "registration_note", "withdrawn", "history",
           "counted", "paper_statement", "paper_source", "paper_numbers", "paper_evidence", "paper_effects",
           "paper_size"]
INTERVAL = "_interval"  # evaluate's per-row ``level -> (low, high)`` (claim_tests.Result.interval); decide drops it
RAW_LEVEL = 1 - stats.ALPHA  # the interval of a row in no family: at the unadjusted α


def comparison_text(claim: ClaimSpec) -> str:
    """What is compared, in words: ``cc − baseline (studio)``."""
    where = f" ({', '.join(claim.scenes)})" if claim.scenes and claim.test != "interaction" else ""
    if claim.test == "decoupled":
        return f"some pair equal in {claim.metric} (±{claim.sesoi:g}) but not in {claim.versus}{where}"
    if claim.test == "dissociated":
        return f"some pair: {claim.metric} not worse (by {claim.sesoi:g}) but {claim.versus} worse{where}"
    if claim.test == "spread":
        return f"SD of {claim.a}{where}"
    if claim.test == "variance":
        return f"SD {claim.a} / SD {claim.b}{where}"
    if claim.test == "interaction":
        pairs = claim.pairs or ((claim.a, claim.b),) * 2
        return " − ".join(f"({a} − {b}) on {s}" for s, (a, b) in zip(claim.scenes, pairs))
    if claim.test == "contrast":
        return " and ".join(" ".join(f"{k:+g}·{v}" for v, k in w) for w in claim.contrasts) + where
    return f"{claim.a} − {claim.b or '0'}{where}"


def _row(claim: ClaimSpec, scene: str, scope: str, study: str, register: Register | None) -> dict:
    found = register.role(study, claim.id) if register is not None and study else None
    statement, role = found if found else (None, "")
    return {"id": claim.id if not scene else f"{claim.id}[{scene}]", "claim": claim.id, "group": claim.group,
            "statement": claim.statement, "metric": claim.metric, "test": claim.test, "expect": claim.expect,
            "comparison": comparison_text(claim), "scene": scene, "scope": scope, "method": "", "n": "", "unit": "",
            "effect": math.nan, "ci_low": math.nan, "ci_high": math.nan, "ci90_low": math.nan, "ci90_high": math.nan,
            "ci_adj_low": math.nan, "ci_adj_high": math.nan, "ci_adj_level": math.nan, "sesoi": claim.sesoi,
            "sesoi_source": claim.sesoi_source, "stat_name": "", "statistic": math.nan,
            "p": math.nan, "p_tost": math.nan, "p_outside": math.nan, "p_het": math.nan, "p_adj": math.nan,
            "p_tost_adj": math.nan, "family": "", "family_size": math.nan, "verdict": NOT_TESTED, "exploratory": False,
            "interval_note": "", "raw_verdict": "",
            "n_needed": math.nan, "power_test": "", "power_param": math.nan, "note": "", "detail": "",
            "role": role, "statement_id": statement.id if statement else "", "registered_commit": "",
            "role_commit": "", "first_run_commit": "", "registered_before_runs": "unknown",
            "registration_note": "not computed", "withdrawn": claim.withdrawn, "history": " / ".join(claim.history),
            "counted": False,
            **paper_columns(statement if role == DECIDES else None, claim.test), "paper_size": "", INTERVAL: None}


def _tested(row: dict, df: pd.DataFrame, claim: ClaimSpec, scenes: tuple[str, ...]) -> dict:
    absent = C.not_exercised(df, claim, scenes)
    if absent:
        return {**row, "verdict": NOT_EXERCISED, "note": absent}
    try:
        res = claim_compare.compare(df, claim, scenes)
    except ValueError as err:
        return {**row, "note": str(err)}
    equivalence_claim = claim.expect == "equivalent"
    row = {**row, "method": res.method + ("; contradicted by the minimal-effect test (|effect| > SESOI)"
                                          if equivalence_claim else ""),
           "n": res.n, "unit": instance_unit.unit_text(df, claim, scenes), "effect": res.effect,
           "ci_low": res.ci[0], "ci_high": res.ci[1], "ci90_low": res.ci90[0], "ci90_high": res.ci90[1],
           "stat_name": res.stat_name, "statistic": res.statistic, "p": res.p_outside if equivalence_claim else res.p,
           "p_tost": res.p_tost, "p_outside": res.p_outside, "detail": res.detail, "verdict": INCONCLUSIVE,
           "power_test": res.power[0], "power_param": res.power[1], INTERVAL: res.interval}
    if claim.test == "spread":
        return {**row, "verdict": DESCRIBED, "p": math.nan, "p_tost": math.nan}
    if not np.isfinite(row["p"]):
        row.update(verdict=NOT_TESTED, note="no spread in the data: the test is undefined")
    return row


def evaluate(df: pd.DataFrame, claims: tuple[ClaimSpec, ...] | list[ClaimSpec], study: str = "",
             register: Register | None = None, pooled: frozenset[str] = frozenset()) -> pd.DataFrame:
    """One row per hypothesis (``COLUMNS``) with raw p-values; verdicts need ``decide``. A claim
    in ``pooled`` (one run until decided: one decision over its scenes) is never split by scene."""
    rows = []
    for c in claims:
        why = C.missing(df, c)
        if why:
            rows.append({**_row(c, "", "pooled" if len(c.scenes) != 1 else c.scenes[0], study, register),
                         "note": why})
            continue
        p_het, per_scene = claim_compare.scene_split(df, c)
        signs = {np.sign(v) for v in per_scene.values() if v != 0}
        if p_het < stats.ALPHA and len(signs) > 1 and c.id not in pooled:  # never pooled over opposite signs
            for scene in per_scene:
                row = _row(c, scene, f"scene-dependent (heterogeneity p = {p_het:.2g})", study, register)
                rows.append({**_tested(row, df, c, (scene,)), "p_het": p_het})
            continue
        used = list(c.scenes) or list(dict.fromkeys(C.finished(df, c.metric).scene))
        scope = ", ".join(used) + (" (pooled)" if len(used) > 1 and c.test != "interaction" else "")
        rows.append({**_tested(_row(c, "", scope, study, register), df, c, c.scenes), "p_het": p_het})
    return pd.DataFrame(rows, columns=[*COLUMNS, INTERVAL])


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
    if expect == "equivalent":  # "≈": p_adj is the minimal-effect test's (|effect| > SESOI)
        return REPRODUCED if equivalent else CONTRADICTED if different else INCONCLUSIVE
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


def counts(row: pd.Series) -> bool:
    """Does the row enter its family? Extension and convention claims do; a paper claim only when
    it decides its statement; never a withdrawn claim, evidence, a description or an untested row."""
    if row.verdict not in DECIDED or row.withdrawn or row.role in (AS_EVIDENCE, REPLACED):
        return False
    return row.group != "paper" or row.role in ("", DECIDES)  # "": a claim outside any register (its own statement)


def _needed(row: pd.Series, alpha: float) -> float:
    """Runs per arm (pairs) for 80% power at the SESOI and ``alpha``, for the test the row used."""
    kind, param = row.power_test, row.power_param
    if kind == "iu":  # an existential dissociation: ``existential.IUPower``
        return param.needed(alpha)
    param = float(param)
    if kind in ("t_paired", "t_ind"):
        return stats.n_for_t(row.sesoi, param, paired=kind == "t_paired", alpha=alpha)
    if kind == "pm":
        return stats.n_for_pm(row.sesoi, rho=param, alpha=alpha)
    if kind == "bf":
        return stats.n_for_bf(row.sesoi)
    return math.nan


def by_equivalence(row: pd.Series) -> bool:
    """Did the equivalence test decide the row (an equivalent row, or one reproduced by
    equivalence: a "≈" claim, or a ``not_higher`` / ``not_lower`` claim within ±SESOI)?"""
    return row.verdict == EQUIVALENT or (row.verdict == REPRODUCED and (
        row.expect == "equivalent" or (row.expect in ("not_higher", "not_lower")
                                       and row.p_tost_adj < row.get("alpha", stats.ALPHA))))


def adjusted_level(row: pd.Series, level_d: float, level_e: float, stop: float) -> float:
    """The confidence level of the interval the verdict used (``stats.holm_levels``): a row
    rejected at Holm step i by its difference test (or, for a "≈" claim, its minimal-effect test)
    at 1 − α_i; by its equivalence test at 1 − 2α_i (TOST at α_i is the (1 − 2α_i) interval inside
    ±SESOI); a row not rejected at 1 − α of the step where Holm stopped."""
    if by_equivalence(row) and np.isfinite(level_e):
        return 1 - 2 * level_e
    if row.verdict in (REPRODUCED, CONTRADICTED) and np.isfinite(level_d):
        return 1 - level_d
    return 1 - stop


def interval_note(row: pd.Series) -> str:
    """What a decided row's adjusted interval says beyond the verdict: that it lies wholly beyond
    the SESOI on one side (the claimed direction or the opposite), or outside ±SESOI for a "≈"
    claim; "" otherwise, and for tests whose effect has no SESOI band (existential, spread)."""
    if row.test in ("decoupled", "dissociated", "spread") or not np.isfinite(row.ci_adj_low):
        return ""
    adjusted = row.copy()
    adjusted["ci_low"], adjusted["ci_high"] = row.ci_adj_low, row.ci_adj_high
    _, low, high = in_sesoi_units(adjusted)
    below, above = ("1/SESOI", "SESOI") if row.test == "variance" else ("−SESOI", "+SESOI")
    if row.expect == "equivalent":  # either side is against a "≈" claim
        return (f"the whole adjusted interval lies below {below} (against the claim)" if high < -1 else
                f"the whole adjusted interval lies above {above} (against the claim)" if low > 1 else "")
    wanted = -1 if row.expect in ("lower", "not_higher") else 1
    if high < -1:
        return f"the whole adjusted interval lies below {below} ({_side(wanted < 0)} direction)"
    if low > 1:
        return f"the whole adjusted interval lies above {above} ({_side(wanted > 0)} direction)"
    return ""


def _side(claimed: bool) -> str:
    return "the claimed" if claimed else "the opposite"


def held_shares(rows: pd.DataFrame) -> pd.Series:
    """The α each study's sequential rows among ``rows`` hold, one share per study (its claims of
    a group hold it together: ``sequential_study.Design.alpha``); a frame without ``study`` is
    one study's."""
    if rows.empty:
        return pd.Series(dtype=float)
    return rows.groupby("study").seq_alpha.first() if "study" in rows else rows.seq_alpha.iloc[:1]


def sequential_rows(frame: pd.DataFrame) -> pd.Series:
    """Which counted rows a sequential design decides (``report.sequential_rows``: a
    ``seq_verdict``); False everywhere for a frame without one."""
    if "seq_verdict" not in frame or frame.empty:
        return pd.Series(False, index=frame.index)
    text = frame.seq_verdict.astype(object).fillna("").astype(str)
    return frame.counted.astype(bool) & (text != "")


def decide(frame: pd.DataFrame, method: str = CORRECTION, label: str = "") -> pd.DataFrame:
    """``frame`` with ``p_adj``, ``p_tost_adj``, ``family``, ``counted`` and ``verdict`` per row: the
    counted rows of each group are one family, corrected with ``method`` over their difference
    and equivalence p-values together; the other rows keep their raw p and say what they are.

    Each tested row also gets the interval its verdict used (``ci_adj_low``, ``ci_adj_high`` at
    ``ci_adj_level``: ``adjusted_level``; 95% for rows in no family) from ``evaluate``'s per-row
    interval, which ``decide`` then drops (a frame decided again keeps the intervals it has);
    ``interval_note`` when that interval lies wholly beyond the SESOI; ``exploratory`` for a
    counted row not registered before its runs (``registered_before_runs``: ``spec.registration``).
    A row a sequential design decides (``seq_verdict``) takes that verdict and stays out of its
    group's Holm, which runs at α less the sequential rows' shares (``alpha`` per row)."""
    out = frame.copy()
    if INTERVAL not in out:
        out[INTERVAL] = None
    out["counted"] = out.apply(counts, axis=1) if len(out) else []
    seq = sequential_rows(out)
    out["alpha"] = stats.ALPHA
    levels = pd.DataFrame(math.nan, index=out.index, columns=["d", "e", "stop"])
    for group, idx in out[out.counted].groupby("group").groups.items():
        run_until = [i for i in idx if seq[i]]
        idx = [i for i in idx if not seq[i]]
        held = float(held_shares(out.loc[run_until]).sum())
        alpha = max(0.0, stats.ALPHA - held)
        for i in run_until:
            out.at[i, "family"] = (f"{group}{label}: run until decided at α {float(out.at[i, 'seq_alpha']):.3g};"
                                   f" the fixed-n rows' Holm at α {alpha:.3g}")
        if not idx:
            continue
        p, p_tost = out.loc[idx, "p"].to_numpy(float), out.loc[idx, "p_tost"].to_numpy(float)
        p_adj, p_tost_adj = stats.union_adjust(p, p_tost, method)
        m = stats.family_size(p, p_tost)
        out.loc[idx, "p_adj"], out.loc[idx, "p_tost_adj"] = p_adj, p_tost_adj
        rest = f" at α {alpha:.3g} (the rows run until decided hold the rest)" if run_until else ""
        out.loc[idx, "family"] = f"{group}{label}: {method.capitalize()} over {m} hypotheses{rest}"
        out.loc[idx, "family_size"] = m
        out.loc[idx, "alpha"] = alpha
        if method == "holm":  # the step levels are Holm's
            level_d, level_e, stop = stats.holm_levels(p, p_tost, alpha)
            levels.loc[idx, "d"], levels.loc[idx, "e"], levels.loc[idx, "stop"] = level_d, level_e, stop
    for i in out.index:
        r = out.loc[i]
        if r.verdict == DESCRIBED and r.role == DECIDES:
            out.at[i, "paper_size"] = size_text(r.paper_effects, float(r.effect), float(r.ci_low), float(r.ci_high),
                                                r.test)
        if r.verdict not in DECIDED:
            if r.withdrawn or r.role == REPLACED:
                out.at[i, "raw_verdict"], out.at[i, "verdict"] = r.verdict, WITHDRAWN
            _interval_at(out, i, RAW_LEVEL if r.verdict == DESCRIBED else math.nan)
            continue
        if not r.counted:  # shown with its unadjusted verdict, in no family
            out.at[i, "raw_verdict"] = verdict(r.expect, float(r.effect), r.test, float(r.p), float(r.p_tost))
            out.at[i, "verdict"] = WITHDRAWN if r.withdrawn or r.role == REPLACED else EVIDENCE
            _interval_at(out, i, RAW_LEVEL)
            continue
        if seq[i]:  # decided by the sequential replay (``report.sequential_rows``)
            v = str(r.seq_verdict)
            out.at[i, "p_adj"], out.at[i, "p_tost_adj"] = math.nan, math.nan
        else:
            v = verdict(r.expect, float(r.effect), r.test, float(r.p_adj), float(r.p_tost_adj), float(r.alpha))
        out.at[i, "verdict"] = v
        out.at[i, "exploratory"] = r.registered_before_runs == "no"
        if v == INCONCLUSIVE:
            out.at[i, "n_needed"] = (float(r.seq_needed) if seq[i] else
                                     _needed(r, float(r.alpha) / max(1.0, float(r.family_size))))
        if seq[i]:
            _interval_at(out, i, RAW_LEVEL)  # a naive 95% interval: no repeated-confidence interval is computed
            out.at[i, "interval_note"] = ""
            if r.role == DECIDES:
                out.at[i, "paper_size"] = size_text(r.paper_effects, float(r.effect), float(r.ci_low),
                                                    float(r.ci_high), r.test)
            continue
        if r.role == DECIDES:
            out.at[i, "paper_size"] = size_text(r.paper_effects, float(r.effect), float(r.ci_low), float(r.ci_high),
                                                r.test)
        _interval_at(out, i, adjusted_level(out.loc[i], *levels.loc[i]))
        out.at[i, "interval_note"] = interval_note(out.loc[i])
    return out.drop(columns=INTERVAL)


def _interval_at(out: pd.DataFrame, i: object, level: float) -> None:
    """Row ``i``'s interval at ``level`` from its test (``INTERVAL``); kept as it is without one."""
    interval = out.at[i, INTERVAL]
    if callable(interval) and np.isfinite(level):
        out.at[i, "ci_adj_low"], out.at[i, "ci_adj_high"] = interval(level)
        out.at[i, "ci_adj_level"] = level


def in_sesoi_units(row: pd.Series) -> tuple[float, float, float]:
    """(effect, ci low, ci high) divided by the SESOI (log scale for SD ratios): ±1 is the band
    of no interest, the forest plot's axis."""
    if row.test == "variance":
        scale = math.log(row.sesoi)
        return tuple(math.log(v) / scale if v > 0 else math.nan for v in (row.effect, row.ci_low, row.ci_high))
    return row.effect / row.sesoi, row.ci_low / row.sesoi, row.ci_high / row.sesoi
