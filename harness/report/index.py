"""``reports/index.md`` (``study index``): the page a reader opens first.

It opens, when some of its runs were made by another trainer than this checkout's, with a note
saying so: which trainers, the command that refreshes them (``make reports``) and its expected
time on this machine (``report.currency``: the plan and rates of ``harness.cli.reports_plan``);
a current page has none. Then, before any other section, one line per statement of the register
(``glance_section``): the statement, the paper's number, our effect with the interval its verdict
used (Holm-adjusted), the verdict (⚑ / exploratory: registered after its runs, computed from git)
and a one-clause reason. Then the details: one row per statement of the paper (the register,
``studies/_paper.yaml``), counted once: the paper's numbers with the spread it reports for that
configuration and the paper's own evidence
(is its difference distinguishable from its own spread?), the claim that decides the statement
with its smallest effect of interest, our effect with its 95% CI, n and the family-corrected p
that decided it, the verdict on the direction, and beside it the paper's *size* against ours.
Other conditions of a statement (another scene, a larger budget) are shown in its row and
counted nowhere. Then the metric conventions, this project's own extensions (a row per claim),
the claims withdrawn or rewritten after their runs with their results, the forest plot, the
speed–accuracy and stability charts, stale reports and studies without runs.

The verdicts come from one decision over every study's claims (``report.families``), which the
study pages show too. A study the store has no runs of is read from its report under the
reports root (its ``runs.csv``). The page carries no timestamp, so the same runs give the same page
(a stale one's expected time is this machine's).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

import pandas as pd

from harness.analysis import verdicts as V
from harness.report import USER_REPORTS
from harness.report.answers import answers_markdown
from harness.report.claims_table import (
    EXPLORATORY,
    POST_HOC,
    VERDICT_MARK,
    VERDICT_RULES,
    effect_text,
    exploratory,
    mark_text,
    p_decided_text,
    sesoi_text,
    verdict_text,
)
from harness.report.currency import plan_frame, stale_note
from harness.report.design_note import design_paragraph, family_text
from harness.report.families import StudyClaims, decide_all, family_verdicts, forget
from harness.report.findings import write_findings
from harness.report.fmt import text
from harness.report.forest import disagreements, forest_plot
from harness.report.glance import glance_section
from harness.spec.paper_register import Register, Statement
from harness.spec.study_files import load_register
from harness.spec.study_schema import CLAIM_GROUPS
from harness.spec.throughput import MEASURED_JOBS, estimate
from harness.tracking.provenance import all_current, checkout_fingerprint

__all__ = ["StudyClaims", "decide_all", "index_markdown", "stale_studies", "write_claims_index"]

CHARTS = (("speed_accuracy", "speed_accuracy.png", "Speed against accuracy per scene (PSNR vs training time, render"
                                                    " FPS and model size, each method's Pareto front)"),
          ("stability", "ladders.png", "Stability ladders: PSNR and failure rates (crash, divergence, colour collapse;"
                                       " quality loss) per rung"),
          ("stability", "stability.png", "Stability: PSNR, spread and failure rate per difficulty cell"))
FOREST = "forest.png"
STATEMENT_FAMILIES = ("paper", "convention")  # families whose rows are the register's statements


def stale_studies(entries: list[StudyClaims], current: str) -> list[tuple[str, str]]:
    """(study, why) for every study whose runs were not all made by the trainer ``current`` (or one
    recorded to train the same bits, ``tracking.provenance.same_bits``)."""
    return [(e.study, ", ".join(e.fingerprints) or "none recorded") for e in entries
            if not all_current(e.fingerprints, current)]


def _ours(r: pd.Series) -> str:
    if math.isnan(r.effect):
        return "—"
    return f"{effect_text(r)} ({r.n}, {p_decided_text(r)})"


def _claim_row(r: pd.Series, study: str, report: str) -> str:
    """An extension's row: one claim."""
    return (f"| {study} | **{r.id}**: {r.statement} | {sesoi_text(r)} | {_ours(r)} | {verdict_text(r)} |"
            f" [{study}]({report}) |")


def _condition(r: pd.Series, study: str) -> str:
    """An evidence row inside a statement's row: ``secret3.dense_best_fast_b20k: −2.36 [...] (raw p …) [verdict]``."""
    return f"`{study}.{r.id}`: {_ours(r)} [{r.raw_verdict or r.verdict}]{mark_text(r)}"


def statement_verdict(s: Statement, deciding: list[tuple[str, pd.Series]]) -> str:
    """The statement's verdict: its deciding row's, or why it has none."""
    if s.not_tested:
        return f"{VERDICT_MARK[V.NOT_TESTED]} ({s.not_tested})"
    if not deciding:
        return f"{VERDICT_MARK[V.NOT_TESTED]} (no runs of `{s.decided_by}`)"
    return "; ".join(verdict_text(r) for _, r in deciding)


def _scale(r: pd.Series) -> str:
    """The metric and SESOI a deciding claim is judged on; a two-metric claim's effect is its second metric's."""
    if r.test in ("decoupled", "dissociated"):
        return f"SESOI {sesoi_text(r)} on `{r.metric}`; the effect shown is the other metric's difference"
    return f"`{r.metric}`, SESOI {sesoi_text(r)}"


def _statement_row(s: Statement, rows: dict[str, tuple[str, str, pd.Series]], numbers: str, evidence: str) -> str:
    deciding = [(study, r) for ref, (study, report, r) in rows.items() if ref == s.decided_by]
    decides = "; ".join(f"`{s.decided_by}` ({r.comparison}, {_scale(r)})" for _, r in deciding)
    ours = "; ".join(_ours(r) for _, r in deciding) or "—"
    size = "; ".join(r.paper_size for _, r in deciding if r.paper_size) or "—"
    others = "<br>".join(_condition(rows[ref][2], rows[ref][0]) for ref in s.evidence if ref in rows) or "—"
    link = next((f"[{study}]({report})" for ref, (study, report, _) in rows.items() if ref == s.decided_by), "—")
    return (f"| {s.part} | **{s.id}**: {s.statement} *({s.source})* | {text(numbers) or '—'} | {evidence or '—'} |"
            f" {decides or '—'} | {ours} | {statement_verdict(s, deciding)} | {size} | {others} | {link} |")


def statement_tally(statements: list[Statement], rows: dict[str, tuple[str, str, pd.Series]]) -> str:
    """``26 statements: 5 reproduced, 3 contradicted, … (4 of them exploratory ⚑: …)``."""
    verdicts, late = [], 0
    for s in statements:
        r = rows.get(s.decided_by, ("", "", None))[2] if s.decided_by else None
        verdicts.append(r.verdict if r is not None else V.NOT_TESTED)
        late += int(r is not None and exploratory(r))
    counts = pd.Series(verdicts, dtype=object).value_counts()
    tally = ", ".join(f"{int(counts[v])} {v}" for v in VERDICT_MARK if v in counts)
    flagged = (f" ({late} of them {EXPLORATORY} {POST_HOC}: decided by a claim registered after its runs)"
               if late else "")
    return f"{len(statements)} statements: {tally or 'none'}{flagged}"


def registration_line(allf: pd.DataFrame) -> list[str]:
    """How many counted rows were registered before their runs, by git (``spec.registration``)."""
    if allf.empty or "registered_before_runs" not in allf:
        return []
    counted = allf[allf.counted.astype(bool)]
    if counted.empty:
        return []
    answers = counted.registered_before_runs.value_counts()
    why = sorted({n for n in counted[counted.registered_before_runs == "unknown"].registration_note if n})
    unknown = f"; unknown: {int(answers.get('unknown', 0))} ({'; '.join(why)})" if answers.get("unknown", 0) else ""
    return [f"Registered before their runs, computed from git (the commit that last changed each claim, its arms,"
            f" scenes and place in the register against its first run's commit): {int(answers.get('yes', 0))} of the"
            f" {len(counted)} counted rows; after them ({EXPLORATORY} {POST_HOC}): {int(answers.get('no', 0))}"
            f"{unknown}.", ""]


def _statement_section(title: str, statements: list[Statement], rows: dict[str, tuple[str, str, pd.Series]],
                       frames: pd.DataFrame) -> list[str]:
    lines = [f"## {title}", "",
             "| Part | Statement (source) | Paper (spread for this configuration) | Paper's own evidence | Decided by |"
             " Ours: effect [95% CI] (n, p) | Verdict (direction) | Size: the paper's effect against our CI |"
             " Other conditions (not counted) | Report |", "|---|---|---|---|---|---|---|---|---|---|"]
    for s in statements:
        deciding = rows.get(s.decided_by)
        numbers = deciding[2].paper_numbers if deciding is not None else "; ".join(
            f"{r.dataset}: {r.note or (f'{r.a:g}' if r.a is not None else '—')}" for r in s.numbers)
        evidence = deciding[2].paper_evidence if deciding is not None else ""
        lines.append(_statement_row(s, rows, numbers, evidence))
    return lines + [""]


def _withdrawn_section(entries: list[StudyClaims]) -> list[str]:
    rows = [(e, r) for e in entries for _, r in e.frame.iterrows() if r.verdict == V.WITHDRAWN]
    if not rows:
        return []
    lines = ["## Withdrawn claims, with their results", "",
             "A registered claim is never deleted after its runs: each claim below was withdrawn (its study file"
             " says why and what replaced it) and is shown with its result on these runs, at the unadjusted α and"
             " in no family.", "",
             "| Study | Claim | Why withdrawn | On these runs | History |", "|---|---|---|---|---|"]
    for e, r in rows:
        history = text(r.get("history", "")) if "history" in r else ""
        result = f"{_ours(r)} [{r.raw_verdict}]" + (f" ({r.note})" if r.note else "") + mark_text(r)
        lines.append(f"| {e.study} | **{r.id}**: {r.statement} | {r.withdrawn or '—'} | {result} | {history or '—'} |")
    return lines + [""]


def index_markdown(entries: list[StudyClaims], charts: list[tuple[str, str]], missing: list[str],
                   current: str = "", forest: str = "", register: Register | None = None,
                   todo: tuple[int, str] = (0, ""), answers: list[str] | None = None,
                   studies_dir: Path | None = None) -> str:
    """The page (module docstring); ``entries`` carry frames already decided over every study;
    ``todo``: the runs ``make reports`` would run and their expected time (``refresh``);
    ``studies_dir``: where the study files are (the design paragraph, each row's seconds a run)."""
    register = register or Register()
    frames = [e.frame.assign(study=e.study) for e in entries if not e.frame.empty]
    allf = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=[*V.COLUMNS, "study"])
    rows = {f"{e.study}.{r.claim}": (e.study, e.report, r) for e in entries for _, r in e.frame.iterrows()}
    stale = stale_studies(entries, current) if current else []
    prints = sorted({f for e in entries for f in e.fingerprints})
    lines = ["# The answers: every statement of the paper on our runs", "",
             *(stale_note(prints, current, "make reports", *todo) if current else []), *design_paragraph(studies_dir)]
    paper = [s for s in register.statements if s.family == "paper"]
    lines += glance_section(paper, rows, f"The paper's {len(paper)} statements at a glance", studies_dir=studies_dir)
    lines += glance_section([s for s in register.statements if s.family != "paper"], rows,
                            "Metric conventions at a glance", legend=False, studies_dir=studies_dir)
    lines += ["Regenerate with `make reports` (or `study index --profile quick --out reports`). One row per statement of the paper"
              " (`studies/_paper.yaml`), counted once and decided by one claim; each claim's smallest effect of"
              " interest (SESOI) is its metric's, fixed once per metric on its own scale (docs/sesoi.md); the"
              " verdicts are corrected over the families below, across every study, and the study pages show the"
              " same verdicts.", ""]
    lines += ["## Families", ""]
    for group, what in CLAIM_GROUPS.items():
        sub = allf[(allf.group == group) & allf.counted.astype(bool)] if len(allf) else allf
        fam = family_text(sub)
        statements = [s for s in register.statements if s.family == group]
        if group in STATEMENT_FAMILIES and statements:
            tally = statement_tally(statements, rows)
        else:
            counts = allf[allf.group == group].verdict.value_counts() if len(allf) else pd.Series(dtype=int)
            tally = ", ".join(f"{int(counts.get(v, 0))} {v}" for v in VERDICT_MARK if counts.get(v, 0)) or "no claims"
            late = sum(exploratory(r) for _, r in allf[allf.group == group].iterrows()) if len(allf) else 0
            tally += f" ({late} of them {EXPLORATORY} {POST_HOC})" if late else ""
        if not fam:  # no claim of the group has the runs its tests need
            lines.append(f"- **{group}** ({what}): no hypotheses tested yet" + (
                f" ({tally})." if frames and tally != "no claims" else "."))
            continue
        lines.append(f"- **{group}** ({what}): {fam} (difference and equivalence tests together). {tally}.")
    lines += ["", *registration_line(allf), VERDICT_RULES, ""]
    for group, what in CLAIM_GROUPS.items():
        statements = [s for s in register.statements if s.family == group]
        if group in STATEMENT_FAMILIES and statements:
            lines += _statement_section(f"{what[0].upper() + what[1:]} ({group})", statements, rows, allf)
            continue
        claim_rows = [(e, r) for e in entries for _, r in e.frame.iterrows()
                      if r.group == group and r.verdict != V.WITHDRAWN]
        if not claim_rows:
            continue
        lines += [f"## {what[0].upper() + what[1:]} ({group})", "",
                  "| Study | Claim | SESOI | Ours: effect [95% CI] (n, p) | Verdict | Report |",
                  "|---|---|---:|---|---|---|"]
        lines += [_claim_row(r, e.study, e.report) for e, r in claim_rows]
        lines.append("")
    lines += _withdrawn_section(entries)
    if forest:
        counted = allf[allf.counted.astype(bool)] if len(allf) else allf
        odd = disagreements(counted) if len(counted) else []
        check = ("Each interval excludes 0 (for a \"≈\" claim: lies outside ±SESOI) exactly when its difference test"
                 " rejects, and lies inside ±SESOI exactly when its equivalence test does" + (
                     "." if not odd else f", except for {', '.join(f'`{o}`' for o in odd)}, whose bootstrap or"
                     " weakest-contrast interval is not its test's dual."))
        lines += ["## Every counted claim's effect", "",
                  f"![Every counted claim's effect in units of its smallest effect of interest]({forest})", "",
                  "Effects with the interval each verdict used, divided by each claim's SESOI, signed so that the"
                  " direction the claim expects is to the right (grey: ±1, effects too small to matter): one Holm"
                  " procedure over each family's difference and equivalence p-values together; a row rejected at"
                  " Holm step i of m is drawn at confidence 1 − α/(m − i + 1) (an equivalence at"
                  " 1 − 2α/(m − i + 1), TOST's interval), a row not rejected at 1 − α/(m − j + 1) of the"
                  " step j where Holm stopped. "
                  + check + f" Diamonds: the paper's own effect per dataset; colour: the verdict; {POST_HOC}:"
                  " registered after its runs.", ""]
    quiet = [e for e in entries if e.frame.empty]
    if quiet:
        lines += ["Studies with runs but no claims: " + ", ".join(f"[{e.study}]({e.report})" for e in quiet) + ".", ""]
    lines += answers or []  # the brief's three questions (report.answers), above their figures
    for caption, path in charts:
        lines += [f"## {caption}", "", f"![{caption}]({path})", ""]
    if stale:
        lines += ["## Stale reports", "",
                  f"The trainer code here (fingerprint `{current}`, `harness/tracking/provenance.py`) is not the"
                  " code that made these studies' runs, so their numbers need not be what this code gives;"
                  " `make reports` regenerates them.", "",
                  *[f"- `{s}`: runs made by trainer {why}" for s, why in stale], ""]
    if missing:
        lines += ["## Studies without runs yet", "", *[f"- `{m}`: `study run {m} --profile quick`" for m in missing],
                  ""]
    codes = sorted({c[:7] for e in entries for c in e.code.split(", ") if c})
    same = (" (the commits differ outside the trainer)" if len(codes) > 1 else "") if len(prints) == 1 else ""
    one_bits = len(prints) > 1 and bool(current) and all_current(prints, current)
    if one_bits:
        same = (f" (recorded to train the same bits as `{current}`: `harness/tracking/same_bits.yaml`, each record"
                " with the `study check` that showed it)")
    lines += [f"Runs made by code {', '.join(codes) or 'unknown'}, trainer fingerprint"
              f" {', '.join(f'`{f}`' for f in prints) or 'unknown'}{same}."
              + (" **More than one trainer: regenerate from one.**" if len(prints) > 1 and not one_bits else ""), ""]
    read = [e.study for e in entries if e.source == "committed report"]
    if read:
        lines += ["Read from their committed reports (`<study>/runs.csv`), the tracking store here having no runs"
                  " of them: " + ", ".join(f"`{s}`" for s in read) + ".", ""]
    part = [f"`{e.study}` ({e.source.removeprefix('tracking store and ')})" for e in entries
            if e.source.startswith("tracking store and ")]
    if part:
        lines += ["Read from the tracking store, with the runs it lacks read from their committed reports (same"
                  " trainer bits and determinism domain; each study page's Tracking section): " + ", ".join(part)
                  + ".", ""]
    return "\n".join(lines)


def refresh(entries: list[StudyClaims], current: str, studies_dir: Path | None = None) -> tuple[int, str]:
    """What ``make reports`` would run when some runs are not ``current``'s (its plan:
    ``currency.plan_frame``), and how long that takes here; (0, "") when all are current."""
    if all_current((f for e in entries for f in e.fingerprints), current):
        return 0, ""
    runs = int(plan_frame(studies_dir=studies_dir, trainer=current).to_run.sum())
    return runs, estimate(runs, MEASURED_JOBS).text()


def write_claims_index(reports_root: Path = USER_REPORTS, studies_dir: Path | None = None,
                       echo: Callable[[str], None] = print, profile: str | None = None) -> Path:
    """Write ``reports_root/index.md`` over every study in ``studies_dir``; return its path.

    Each study's claims come from its runs in the tracking store (every planned run of
    ``profile`` when given, else its latest invocation's), or, when the store has none, from its
    report already under ``reports_root`` (``report.families``).
    """
    root = Path(reports_root)
    root.mkdir(parents=True, exist_ok=True)
    forget()  # the index decides afresh from the runs as they are now
    entries, missing = family_verdicts(root, studies_dir, profile)
    register = load_register(studies_dir)
    with_runs = {e.study for e in entries}
    charts = [(caption, f"{study}/{png}") for study, png, caption in CHARTS
              if study in with_runs and (root / study / png).is_file()]
    frames = [e.frame.assign(study=e.study) for e in entries if not e.frame.empty]
    allf = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    if len(allf):
        allf.to_csv(root / "claims.csv", index=False)
    counted = allf[allf.counted.astype(bool)] if len(allf) else allf
    forest = forest_plot(counted, root / FOREST) if len(counted) else None
    path = root / "index.md"
    current = checkout_fingerprint()
    path.write_text(index_markdown(entries, charts, missing, current, FOREST if forest else "", register,
                                   refresh(entries, current, studies_dir), answers_markdown(root), studies_dir))
    write_findings(root, studies_dir)  # every number FINDINGS.md may cite (report.findings)
    n = sum(len(e.frame) for e in entries)
    echo(f"index: {len(register.statements)} statements and {n} claims over {len(entries)} studies with runs"
         f" ({len(missing)} without) written to {path}")
    return path
