"""``reports/index.md`` (``study index``): the page a reader opens first.

One row per claim of every study that has runs in the store (the paper's claim and number,
our effect ± 95% CI with n and Holm p, the verdict, a link to the study's report), then the
speed–accuracy and stability charts when their reports exist. The page carries no
timestamp, so the same store gives the same page.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pandas as pd

from harness.analysis import claims as claims_mod
from harness.report import USER_REPORTS
from harness.report.claims import VERDICT_MARK, effect_text, needed_text
from harness.report.fmt import p_text, text
from harness.report.results import collect
from harness.spec.files import list_studies
from harness.spec.metrics import add_differences
from harness.tracking.provenance import trainer_fingerprint

CHARTS = (("speed_accuracy", "speed_accuracy.png", "Speed against accuracy per scene (PSNR vs train time and"
                                                    " #Gaussians, Pareto fronts)"),
          ("stability", "ladders.png", "Stability ladders: PSNR and failure rate (crash, divergence, collapse) per rung"),
          ("stability", "stability.png", "Stability: PSNR, spread and failure rate per difficulty cell"))


@dataclass
class StudyClaims:
    """One study's entry of the index page."""

    study: str
    question: str
    frame: pd.DataFrame  # claims.evaluate
    report: str  # link to the study's report, relative to the index page
    n_finished: int
    code: str = ""  # git sha(s) of the runs
    fingerprints: tuple[str, ...] = ()  # trainer fingerprints of the finished runs


def stale_studies(entries: list[StudyClaims], current: str) -> list[tuple[str, str]]:
    """(study, why) for every study whose runs were not all made by the trainer ``current``."""
    return [(e.study, ", ".join(e.fingerprints) or "none recorded") for e in entries
            if set(e.fingerprints) != {current}]


def index_markdown(entries: list[StudyClaims], charts: list[tuple[str, str]], missing: list[str],
                   current: str = "") -> str:
    """The page: a claims table over every study, the charts, the studies whose runs another
    trainer made (stale), and the studies without runs."""
    lines = ["# The answers: every claim of the paper on our runs", "",
             "One row per claim of every study with runs in the store. Effect = the compared quantity"
             " (see the study's report for the exact test) with its 95% CI; n = runs or seed pairs;"
             " p Holm-corrected within the study. Regenerate with `make reports` (or `study index`).", "",
             "| Study | Claim | Paper | Ours: effect [95% CI] (n, p) | Verdict | Report |",
             "|---|---|---|---|---|---|"]
    for e in entries:
        for _, r in e.frame.iterrows():
            ours = "—" if math.isnan(r.effect) else f"{effect_text(r)} ({r.n}, p = {p_text(r.p_holm)})"
            note = f" ({r.note})" if r.note else ""
            need = needed_text(r)
            if need.startswith("none"):
                need = f"; no n gives 80% power: {need[6:-1]}"
            elif need:
                need = f"; ≈{need}{'' if need.endswith('runs') else ' runs/arm'} for 80% power"
            lines.append(f"| {e.study} | {r.statement} | {text(r.paper_number)} | {ours} |"
                         f" {VERDICT_MARK[r.verdict]}{note}{need} | [{e.study}]({e.report}) |")
        if e.frame.empty:
            lines.append(f"| {e.study} | (no claims stated) | — | — | — | [{e.study}]({e.report}) |")
    lines.append("")
    counts = pd.Series([v for e in entries for v in e.frame.verdict]).value_counts()
    if len(counts):
        lines += ["Verdicts: " + ", ".join(f"{int(counts.get(v, 0))} {v}" for v in VERDICT_MARK) + ".", ""]
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
    codes = sorted({c for e in entries for c in e.code.split(", ") if c})
    lines += [f"Runs made by code {', '.join(codes) or 'unknown'}."
              + (" **More than one code version: regenerate from one.**" if len(codes) > 1 else ""), ""]
    return "\n".join(lines)


def collect_study_claims(name: str, studies_dir: Path | None = None) -> StudyClaims | None:
    """The study's claims evaluated on its latest invocation's runs; None when none finished."""
    data = collect(name, None, studies_dir)
    n_done = int((data.df.status == "FINISHED").sum())
    if n_done == 0:
        return None
    frame = claims_mod.evaluate(add_differences(data.df), data.study.claims)
    report = (Path(name) / "index.md").as_posix()
    return StudyClaims(name, data.study.question, frame, report, n_done, ", ".join(data.code_versions()),
                       tuple(data.trainer_fingerprints()))


def write_claims_index(reports_root: Path = USER_REPORTS, studies_dir: Path | None = None,
                       echo: Callable[[str], None] = print) -> Path:
    """Write ``reports_root/index.md`` over every study in ``studies_dir``; return its path."""
    root = Path(reports_root)
    root.mkdir(parents=True, exist_ok=True)
    entries, missing = [], []
    for name in list_studies(studies_dir):
        entry = collect_study_claims(name, studies_dir)
        (entries.append(entry) if entry is not None else missing.append(name))
    with_runs = {e.study for e in entries}
    charts = [(caption, f"{study}/{png}") for study, png, caption in CHARTS
              if study in with_runs and (root / study / png).is_file()]
    path = root / "index.md"
    path.write_text(index_markdown(entries, charts, missing, trainer_fingerprint()))
    n = sum(len(e.frame) for e in entries)
    echo(f"index: {n} claims over {len(entries)} studies with runs ({len(missing)} without) written to {path}")
    return path
