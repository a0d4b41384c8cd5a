"""The index's first tables: one line per statement of the paper register (``glance_section``),
the paper's number, ours with the interval its verdict used (Holm-adjusted), the verdict with its
registration mark, and a one-clause reason; the details follow on the page (``report.index``)."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import pandas as pd

from harness.analysis import stats, verdicts as V
from harness.report.claims_table import POST_HOC, VERDICT_MARK, deciding_p, effect_text, mark_text, needed_text
from harness.report.fmt import p_text, text
from harness.spec.paper_register import Statement


def short_statement(s: Statement, limit: int = 90) -> str:
    """The statement up to its dash (the paper's example after it), else whole when short, else cut at a word."""
    head = s.statement.split(" — ")[0].rstrip(".")
    if len(head) <= limit:
        return head
    return head[:limit].rsplit(" ", 1)[0] + " …"


def paper_number(s: Statement, test: str) -> str:
    """The paper's effect per dataset (an SD ratio or an SD for spread claims; else its note)."""
    parts = []
    for n in s.numbers:
        if test == "variance" and n.a is None and n.a_std is not None and n.b_std:
            parts.append(f"{n.dataset} ×{n.a_std / n.b_std:.2f}")
        elif test == "spread" and n.a is None and n.a_std is not None:
            parts.append(f"{n.dataset} SD {n.a_std:g}")
        elif n.effect is not None:
            parts.append(f"{n.dataset} {n.effect:+.3g}")
        elif n.note:
            parts.append(f"{n.dataset}: {n.note}")
    return text("; ".join(parts)) or "—"


def adjusted_text(r: pd.Series) -> str:
    """``+0.42 [+0.31, +0.53] at 99.87%``: the effect with the interval its verdict used."""
    level = r.get("ci_adj_level", math.nan)
    if math.isnan(r.effect) or not isinstance(level, float) or math.isnan(level):
        return "—" if math.isnan(r.effect) else effect_text(r)
    shown = r.copy()
    shown["ci_low"], shown["ci_high"] = r.ci_adj_low, r.ci_adj_high
    return f"{effect_text(shown)} at {100 * level:.4g}%"


def reason(s: Statement, r: pd.Series | None, run_seconds: float = math.nan) -> str:
    """One clause: why the statement's verdict is what it is; an inconclusive row says the runs a
    fixed design would need (``claims_table.needed_text``) and, given the study's ``run_seconds``,
    their CPU hours."""
    if s.not_tested:
        return s.not_tested
    if r is None:
        return f"no runs of `{s.decided_by}`"
    if r.verdict in (V.NOT_TESTED, V.NOT_EXERCISED):
        return r.note or r.verdict
    if r.verdict == V.DESCRIBED:
        return "a spread described beside the paper's; no test"
    beyond = f"; {r.interval_note}" if isinstance(r.get("interval_note", ""), str) and r.get("interval_note") else ""
    if isinstance(r.get("seq_text"), str) and r.seq_text and r.get("counted", False):
        return r.seq_text  # decided by its study's sequential design (report.sequential_rows)
    if r.verdict == V.INCONCLUSIVE:
        tost = f", TOST p = {p_text(r.p_tost_adj)}" if not math.isnan(r.p_tost_adj) else ""
        alpha = r.get("alpha", stats.ALPHA)
        at = ("the family's α" if not isinstance(alpha, float) or math.isnan(alpha) or alpha >= stats.ALPHA
              else f"the α {alpha:.3g} the family's rows run until decided leave")
        need = needed_text(r) if "n_needed" in r and "family_size" in r else ""
        if need and math.isfinite(float(r.n_needed)) and run_seconds > 0:
            need += f", {float(r.n_needed) * run_seconds / 3600:.3g} CPU h an arm at {run_seconds:g} s a run"
        return f"no test rejects at {at} (Holm p = {p_text(r.p_adj)}{tost}){beyond}" + (f"; {need}" if need else "")
    p = p_text(deciding_p(r))
    if V.by_equivalence(r):
        return f"the equivalence test rejects (Holm TOST p = {p}): within ±SESOI{beyond}"
    if r.expect == "exists":
        return f"some pair of arms shows it (Holm p = {p}){beyond}"
    if r.expect == "equivalent":
        return f"the minimal-effect test puts it outside ±SESOI (Holm p = {p}){beyond}"
    side = "the claimed" if r.verdict == V.REPRODUCED else "the opposite"
    return f"the difference test rejects (Holm p = {p}), in {side} direction{beyond}"


@functools.lru_cache(maxsize=32)
def _run_seconds(study: str, studies_dir: Path | None = None) -> float:
    """The seconds a quick run of ``study`` takes, as its study file in ``studies_dir`` states
    (NaN: not stated)."""
    from harness.spec.study_files import load_study

    try:
        prof = load_study(study, studies_dir).profiles.get("quick")
    except Exception:  # noqa: BLE001  (a study file that no longer loads: no figure, not a failed page)
        return math.nan
    return float(prof.run_seconds) if prof is not None and prof.run_seconds > 0 else math.nan


def glance_section(statements: list[Statement], rows: dict[str, tuple[str, str, pd.Series]],
                   title: str = "Every statement at a glance", legend: bool = True,
                   studies_dir: Path | None = None) -> list[str]:
    """A table of one line per statement (its details follow below): the page opens with the paper's
    statements, then the metric conventions'; ``studies_dir``: where the study files are (each
    undecided row's CPU hours)."""
    if not statements:
        return []
    lines = [f"## {title}", "",
             "| Statement | Paper | Ours: effect [adjusted interval] | Verdict | Why |", "|---|---|---|---|---|"]
    for s in statements:
        r = rows[s.decided_by][2] if s.decided_by in rows else None
        if r is None:
            verdict = VERDICT_MARK[V.NOT_TESTED]
        else:
            scope = " — scene-dependent" if str(r.scope).startswith("scene-dependent") else ""
            verdict = VERDICT_MARK[r.verdict] + scope + mark_text(r)
        ours = adjusted_text(r) if r is not None else "—"
        seconds = _run_seconds(rows[s.decided_by][0], studies_dir) if r is not None else math.nan
        lines.append(f"| **{s.id}**: {short_statement(s)} | {paper_number(s, r.test if r is not None else '')} |"
                     f" {ours} | {verdict} | {text(reason(s, r, seconds))} |")
    if not legend:
        return lines + [""]
    return lines + ["", "The adjusted interval is the one the verdict used: at the confidence of the Holm step"
                    " that decided the row (1 − α/(m − i + 1) for a difference rejected at step i of m;"
                    " 1 − 2α/(m − i + 1) for an equivalence, TOST's interval; for a row not rejected,"
                    f" 1 − α/(m − j + 1) at the step j where Holm stopped). {POST_HOC}: registered after its runs"
                    " (computed from git). Details per statement follow.", ""]
