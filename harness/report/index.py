"""``reports/index.md`` (``study index``): the page a reader opens first.

It opens, when some of its runs were made by another trainer than this checkout's, with a
note saying so: which trainers, the command that refreshes them (``make reports``) and its
expected time on this machine (``report.currency``: the plan and rates of
``harness.cli.reports_plan``); a current page has none. Then comes the forest plot (every
claim's effect in units of its smallest effect of interest, the paper's own effect marked); the
page names the families its verdicts are corrected over
(``analysis.verdicts``: one family per claim group over every study, not per study), tallies
the verdicts per family, and has one row per hypothesis: the paper's numbers and the paper's
own evidence (is its difference distinguishable from its own spread?), the SESOI, our effect
with its 95% CI, n and family-corrected p, and the verdict, linked to the study's report.
Then the speed–accuracy and stability charts, stale reports and studies without runs. A study
the store has no runs of is read from its report under the reports root (its ``runs.csv``). The
page carries no timestamp, so the same store gives the same page (a stale one's expected time
is this machine's).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pandas as pd

from harness.analysis import verdicts as V
from harness.report import USER_REPORTS
from harness.report.claims_table import VERDICT_MARK, VERDICT_RULES, effect_text, sesoi_text, verdict_text
from harness.report.currency import plan_frame, stale_note
from harness.report.findings import write_findings
from harness.report.fmt import p_text, text
from harness.report.forest import forest_plot
from harness.report.results import collect, trainer_fingerprints
from harness.spec.metrics import add_differences
from harness.spec.study_files import list_studies, load_study
from harness.spec.study_schema import CLAIM_GROUPS
from harness.spec.throughput import MEASURED_JOBS, estimate
from harness.tracking.provenance import checkout_fingerprint

CHARTS = (("speed_accuracy", "speed_accuracy.png", "Speed against accuracy per scene (PSNR vs train time and"
                                                    " #Gaussians, Pareto fronts)"),
          ("stability", "ladders.png", "Stability ladders: PSNR and failure rate (crash, divergence, collapse) per rung"),
          ("stability", "stability.png", "Stability: PSNR, spread and failure rate per difficulty cell"))
FOREST = "forest.png"
CODE_AT = re.compile(r"code at ([0-9a-f]{7,40}(?:, [0-9a-f]{7,40})*)")  # a study page's provenance line


@dataclass
class StudyClaims:
    """One study's entry of the index page."""

    study: str
    question: str
    frame: pd.DataFrame  # verdicts.evaluate, then decide_all
    report: str  # link to the study's report, relative to the index page
    n_finished: int
    code: str = ""  # git sha(s) of the runs
    fingerprints: tuple[str, ...] = ()  # trainer fingerprints of the finished runs
    source: str = "tracking store"  # or "committed report" (its runs.csv)


def stale_studies(entries: list[StudyClaims], current: str) -> list[tuple[str, str]]:
    """(study, why) for every study whose runs were not all made by the trainer ``current``."""
    return [(e.study, ", ".join(e.fingerprints) or "none recorded") for e in entries
            if set(e.fingerprints) != {current}]


def _row(r: pd.Series, study: str, report: str) -> str:
    ours = "—" if math.isnan(r.effect) else f"{effect_text(r)} ({r.n}, p = {p_text(r.p_adj)})"
    evidence = r.paper_evidence or ("no numbers" if not r.paper_numbers else "—")
    return (f"| {study} | **{r.id}**: {r.statement} | {text(r.paper_numbers)} | {evidence} | {sesoi_text(r)} |"
            f" {ours} | {verdict_text(r)} | [{study}]({report}) |")


def index_markdown(entries: list[StudyClaims], charts: list[tuple[str, str]], missing: list[str],
                   current: str = "", forest: str = "", todo: tuple[int, str] = (0, "")) -> str:
    """The page (module docstring); ``entries`` carry frames already decided over all studies;
    ``todo``: the runs ``make reports`` would run and their expected time (``refresh``)."""
    frames = [e.frame.assign(study=e.study) for e in entries if not e.frame.empty]
    allf = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=[*V.COLUMNS, "study"])
    prints = sorted({f for e in entries for f in e.fingerprints})
    lines = ["# The answers: every claim of the paper on our runs", "",
             *(stale_note(prints, current, "make reports", *todo) if current else []),
             "Regenerate with `make reports` (or `study index --out reports`). Each claim names its smallest"
             " effect of interest (SESOI), fixed in its study file before the runs; the verdicts are corrected"
             " over the families below, across every study.", ""]
    if forest:
        lines += [f"![Every claim's effect in units of its smallest effect of interest]({forest})", "",
                  "Effects and 95% CIs divided by each claim's SESOI (grey: ±1, effects too small to matter);"
                  " diamonds: the paper's own effect per dataset; colour: the verdict.", ""]
    lines += ["## Families", ""]
    for group, what in CLAIM_GROUPS.items():
        sub = allf[allf.group == group]
        fam = next((f for f in sub.family if f), "")
        counts = sub.verdict.value_counts()
        tally = ", ".join(f"{int(counts.get(v, 0))} {v}" for v in VERDICT_MARK if counts.get(v, 0))
        if not fam:  # no claim of the group has the runs its tests need
            lines.append(f"- **{group}** ({what}): no hypotheses tested yet" + (f" ({tally})." if tally else "."))
            continue
        lines.append(f"- **{group}** ({what}): {fam} hypotheses, separately for the difference and the"
                     f" equivalence tests. {tally or 'no claims'}.")
    lines += ["", VERDICT_RULES, ""]
    for group, what in CLAIM_GROUPS.items():
        rows = [(e, r) for e in entries for _, r in e.frame.iterrows() if r.group == group]
        if not rows:
            continue
        lines += [f"## {what[0].upper() + what[1:]} ({group})", "",
                  "| Study | Claim | Paper | Paper's own evidence | SESOI | Ours: effect [95% CI] (n, p) | Verdict |"
                  " Report |", "|---|---|---|---|---:|---|---|---|"]
        lines += [_row(r, e.study, e.report) for e, r in rows]
        lines.append("")
    quiet = [e for e in entries if e.frame.empty]
    if quiet:
        lines += ["Studies with runs but no claims: " + ", ".join(f"[{e.study}]({e.report})" for e in quiet) + ".", ""]
    for caption, path in charts:
        lines += [f"## {caption}", "", f"![{caption}]({path})", ""]
    stale = stale_studies(entries, current) if current else []
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
    lines += [f"Runs made by code {', '.join(codes) or 'unknown'}, trainer fingerprint"
              f" {', '.join(f'`{f}`' for f in prints) or 'unknown'}{same}."
              + (" **More than one trainer: regenerate from one.**" if len(prints) > 1 else ""), ""]
    read = [e.study for e in entries if e.source != "tracking store"]
    if read:
        lines += ["Read from their committed reports (`<study>/runs.csv`), the tracking store here having no runs"
                  " of them: " + ", ".join(f"`{s}`" for s in read) + ".", ""]
    return "\n".join(lines)


def decide_all(entries: list[StudyClaims]) -> list[StudyClaims]:
    """Every study's claims corrected together, one family per claim group."""
    frames = [e.frame.assign(study=e.study) for e in entries if not e.frame.empty]
    if not frames:
        return entries
    decided = V.decide(pd.concat(frames, ignore_index=True), label=" (every study)")
    for e in entries:
        if not e.frame.empty:
            e.frame = decided[decided.study == e.study].drop(columns="study").reset_index(drop=True)
    return entries


def collect_study_claims(name: str, studies_dir: Path | None = None) -> StudyClaims | None:
    """The study's claims evaluated on its latest invocation's runs; None when none finished."""
    data = collect(name, None, studies_dir)
    n_done = int((data.df.status == "FINISHED").sum())
    if n_done == 0:
        return None
    frame = V.evaluate(add_differences(data.df), data.study.claims)
    report = (Path(name) / "index.md").as_posix()
    return StudyClaims(name, data.study.question, frame, report, n_done, ", ".join(data.code_versions()),
                       tuple(data.trainer_fingerprints()))


def committed_study_claims(name: str, root: Path, studies_dir: Path | None = None) -> StudyClaims | None:
    """The study's claims evaluated on the runs of its report under ``root`` (its ``runs.csv``);
    None when there is no report or none of its runs finished.

    For a study the store has no runs of: the index then covers the reports as they are
    committed, each made by the code its page names ("code at ..."), and the stale check
    still compares their trainer fingerprints with this checkout's.
    """
    folder = Path(root) / name
    if not (folder / "runs.csv").is_file():
        return None
    df = pd.read_csv(folder / "runs.csv")
    n_done = int((df.status == "FINISHED").sum())
    if n_done == 0:
        return None
    page = (folder / "index.md").read_text() if (folder / "index.md").is_file() else ""
    code = m.group(1).strip() if (m := CODE_AT.search(page)) else ""
    study = load_study(name, studies_dir)
    frame = V.evaluate(add_differences(df), study.claims)
    return StudyClaims(name, study.question, frame, (Path(name) / "index.md").as_posix(),
                       n_done, code, tuple(trainer_fingerprints(df)), source="committed report")


def refresh(entries: list[StudyClaims], current: str, studies_dir: Path | None = None) -> tuple[int, str]:
    """What ``make reports`` would run when some runs are not ``current``'s (its plan:
    ``currency.plan_frame``), and how long that takes here; (0, "") when all are current."""
    if {f for e in entries for f in e.fingerprints} <= {current}:
        return 0, ""
    runs = int(plan_frame(studies_dir=studies_dir, trainer=current).to_run.sum())
    return runs, estimate(runs, MEASURED_JOBS).text()


def write_claims_index(reports_root: Path = USER_REPORTS, studies_dir: Path | None = None,
                       echo: Callable[[str], None] = print) -> Path:
    """Write ``reports_root/index.md`` over every study in ``studies_dir``; return its path.

    Each study's claims come from its runs in the tracking store, or, when the store has none,
    from its report already under ``reports_root`` (``committed_study_claims``).
    """
    root = Path(reports_root)
    root.mkdir(parents=True, exist_ok=True)
    entries, missing = [], []
    for name in list_studies(studies_dir):
        entry = collect_study_claims(name, studies_dir) or committed_study_claims(name, root, studies_dir)
        (entries.append(entry) if entry is not None else missing.append(name))
    entries = decide_all(entries)
    current = checkout_fingerprint()
    todo = refresh(entries, current, studies_dir)
    with_runs = {e.study for e in entries}
    charts = [(caption, f"{study}/{png}") for study, png, caption in CHARTS
              if study in with_runs and (root / study / png).is_file()]
    frames = [e.frame.assign(study=e.study) for e in entries if not e.frame.empty]
    allf = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    if len(allf):
        allf.to_csv(root / "claims.csv", index=False)
    forest = forest_plot(allf, root / FOREST) if len(allf) else None
    path = root / "index.md"
    path.write_text(index_markdown(entries, charts, missing, current, FOREST if forest else "", todo))
    write_findings(root, studies_dir)  # every number FINDINGS.md may cite (report.findings)
    n = sum(len(e.frame) for e in entries)
    echo(f"index: {n} claims over {len(entries)} studies with runs ({len(missing)} without) written to {path}")
    return path
