"""One decision over every study's claims, shared by ``reports/index.md`` and every study page.

A family's error rate is over every study at once (``analysis.verdicts.decide``), so a study
page cannot decide its claims alone: ``family_verdicts(root)`` evaluates every study's claims
on its runs — from the tracking store, else from its report under ``root`` (``runs.csv``), else
from the committed report in ``reports/`` — and decides them together, once per process. The
index and each page read their rows from it, so the two always show the same verdict, the same
p that decided it and the same family. Each claim's registration — was it registered before its
runs? — is computed from git (``spec.registration``) on the runs it was tested on, before the
decision, which names a counted row registered after its runs exploratory. A study's rows run
until decided take the sequential replay's verdict (``report.sequential_rows``).
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, replace
from pathlib import Path

import pandas as pd

from harness.analysis import verdicts as V
from harness.report import COMMITTED_REPORTS, committed, sequential_rows
from harness.report.results import collect, store_has_runs, trainer_fingerprints
from harness.spec import registration, study_files
from harness.spec.instances import instance_columns
from harness.spec.metrics import add_differences
from harness.spec.paper_register import Register
from harness.spec.runs import Selection, expand
from harness.spec.study_files import list_studies, load_register, load_study

CODE_AT = re.compile(r"code at ([0-9a-f]{7,40}(?:, [0-9a-f]{7,40})*)")  # a study page's provenance line
EVERY_STUDY = " (every study)"


@dataclass
class StudyClaims:
    """One study's claims, evaluated on its runs and decided with every other study's."""

    study: str
    question: str
    frame: pd.DataFrame  # verdicts.evaluate, then decided over every study
    report: str  # link to the study's report, relative to the index page
    n_finished: int
    code: str = ""  # git sha(s) of the runs
    fingerprints: tuple[str, ...] = ()  # trainer fingerprints of the finished runs
    source: str = "tracking store"  # or "committed report" (its runs.csv)


def store_claims(name: str, register: Register, studies_dir: Path | None = None,
                 profile: str | None = None) -> StudyClaims | None:
    """The study's claims on its runs in the tracking store: every planned run of ``profile`` when
    it is given, else its latest invocation's; None when none finished."""
    sel = Selection(profile=profile) if profile else None
    if not store_has_runs(name, sel, studies_dir):  # nothing to find: skip planning every run
        return None
    data = collect(name, sel, studies_dir)
    n_done = int((data.df.status == "FINISHED").sum())
    if n_done == 0:
        return None
    data = committed.fill_missing(data, COMMITTED_REPORTS / name, echo=lambda line: None)
    n_done = int((data.df.status == "FINISHED").sum())
    frame = claims_frame(data.study, data.df, register, studies_dir, profile)
    source = f"tracking store and {len(data.filled.keys)} committed runs" if data.filled is not None else "tracking store"
    return StudyClaims(name, data.study.question, frame, (Path(name) / "index.md").as_posix(), n_done,
                       ", ".join(data.code_versions()), tuple(data.trainer_fingerprints()), source=source)


def report_claims(name: str, root: Path, register: Register, studies_dir: Path | None = None) -> StudyClaims | None:
    """The study's claims on the runs of its report under ``root`` (its ``runs.csv``); None when
    there is no report or none of its runs finished. Its page names the code that made it
    ("code at ..."); the stale check compares its trainer fingerprints with this checkout's."""
    folder = Path(root) / name
    if not (folder / "runs.csv").is_file():
        return None
    df = pd.read_csv(folder / "runs.csv", dtype={"git_sha": str, "start_time": str})  # a sha of digits stays text
    n_done = int((df.status == "FINISHED").sum())
    if n_done == 0:
        return None
    page = (folder / "index.md").read_text() if (folder / "index.md").is_file() else ""
    code = m.group(1).strip() if (m := CODE_AT.search(page)) else ""
    study = load_study(name, studies_dir)
    df = instance_columns(with_fresh_planned(df, study), study)  # a runs.csv may predate the columns
    frame = claims_frame(study, df, register, studies_dir)
    return StudyClaims(name, study.question, frame, (Path(name) / "index.md").as_posix(),
                       n_done, code, tuple(trainer_fingerprints(df)), source="committed report")


def claims_frame(study, df: pd.DataFrame, register: Register, studies_dir: Path | None,
                 profile: str | None = None) -> pd.DataFrame:
    """The study's claims evaluated on its runs frame ``df`` (its sequential design's claims
    unsplit), with their registration from git and the sequential replay's decisions."""
    runs = add_differences(df)
    design = sequential_rows.design_of(study, register, studies_dir, profile)
    frame = with_registration(V.evaluate(runs, study.claims, study.name, register, sequential_rows.claim_ids(design)),
                              df, study.claims, study.name, studies_dir)
    return sequential_rows.annotate(frame, design, runs)


def with_fresh_planned(df: pd.DataFrame, study, profile: str = "quick") -> pd.DataFrame:
    """A committed ``runs.csv`` with a MISSING row for every fresh-instance run the study's
    ``profile`` now plans and the file lacks (a report written before its scenes had instances):
    a runs frame lists every planned run, and the instance-level tests decide from those rows
    what they leave out (``spec.instances.fresh``), so the committed pilot is never tested as a
    fresh instance. Planned from the study file alone (``spec.runs.expand``: no Hydra)."""
    if profile not in study.profiles:
        return df
    have = set(zip(df.variant.astype(str), df.scene.astype(str), df.seed.astype(int)))
    rows = [{"variant": r.variant, "scene": r.scene.name, "seed": r.seed, "status": "MISSING"}
            for r in expand(study, Selection(profile=profile))
            if r.scene.instance > 0 and (r.variant, r.scene.name, r.seed) not in have]
    return pd.concat([df, pd.DataFrame(rows)], ignore_index=True) if rows else df


def with_registration(frame: pd.DataFrame, runs: pd.DataFrame, claims: tuple, study: str,
                      studies_dir: Path | None) -> pd.DataFrame:
    """``frame`` (``verdicts.evaluate``) with each claim's registration from git
    (``spec.registration``): ``registered_commit``, ``role_commit``, ``first_run_commit``,
    ``registered_before_runs`` (yes / no / unknown) and ``registration_note`` (why)."""
    found = registration.registrations(study, claims, runs, Path(studies_dir or study_files.STUDIES_DIR))
    out = frame.copy()
    for i, r in out.iterrows():
        reg = found.get(r.claim)
        if reg is None:
            continue
        out.at[i, "registered_commit"], out.at[i, "role_commit"] = reg.claim_commit, reg.role_commit
        out.at[i, "first_run_commit"], out.at[i, "registered_before_runs"] = reg.first_run_commit, reg.before_runs
        out.at[i, "registration_note"] = reg.why
    return out


def decide_all(entries: list[StudyClaims]) -> list[StudyClaims]:
    """Every study's claims corrected together, one family per claim group."""
    frames = [e.frame.assign(study=e.study) for e in entries if not e.frame.empty]
    if not frames:
        return [replace(e, frame=e.frame.drop(columns=V.INTERVAL, errors="ignore")) for e in entries]
    decided = V.decide(pd.concat(frames, ignore_index=True), label=EVERY_STUDY)
    return [replace(e, frame=decided[decided.study == e.study].drop(columns="study").reset_index(drop=True))
            if not e.frame.empty else replace(e, frame=e.frame.drop(columns=V.INTERVAL, errors="ignore"))
            for e in entries]


@functools.lru_cache(maxsize=4)
def _family_verdicts(root: Path, studies_dir: Path, profile: str | None) -> tuple[tuple[StudyClaims, ...], tuple[str, ...]]:
    register = load_register(studies_dir)
    entries, missing = [], []
    for name in list_studies(studies_dir):
        entry = (store_claims(name, register, studies_dir, profile) or report_claims(name, root, register, studies_dir)
                 or (report_claims(name, COMMITTED_REPORTS, register, studies_dir)
                     if Path(root).resolve() != COMMITTED_REPORTS.resolve() else None))
        (entries.append(entry) if entry is not None else missing.append(name))
    return tuple(decide_all(entries)), tuple(missing)


def family_verdicts(root: Path, studies_dir: Path | None = None,
                    profile: str | None = None) -> tuple[list[StudyClaims], list[str]]:
    """(every study with finished runs, decided together; the studies without runs), for the
    reports under ``root`` (module docstring): each study's runs are every planned run of
    ``profile`` when it is given (``study report --profile``, ``study index --profile``: what
    ``make reports`` writes, whatever subset was run last), else its latest invocation's.
    Computed once per process, ``root`` and ``profile``."""
    entries, missing = _family_verdicts(Path(root), Path(studies_dir or study_files.STUDIES_DIR), profile)
    return [replace(e, frame=e.frame.copy()) for e in entries], list(missing)


def forget() -> None:
    """Drop the cached decision and git answers (a test, or a process that has just written new runs)."""
    _family_verdicts.cache_clear()
    registration.forget()


def study_frame(name: str, root: Path, studies_dir: Path | None = None,
                profile: str | None = None) -> pd.DataFrame | None:
    """One study's rows of the decision over every study (None when the study has no finished runs)."""
    entries, _ = family_verdicts(root, studies_dir, profile)
    return next((e.frame for e in entries if e.study == name), None)


def deciding_verdicts(root: Path, studies_dir: Path | None = None, profile: str | None = None) -> dict[str, str]:
    """Each paper statement's deciding claim and its verdict (``secret5_cc.cc_raises_mean_drift:
    inconclusive``), for the pages that show evidence for it."""
    entries, _ = family_verdicts(root, studies_dir, profile)
    return {r.statement_id: f"decided by `{e.study}.{r.claim}`: {r.verdict}" for e in entries
            for _, r in e.frame.iterrows() if r.statement_id and r.role == V.DECIDES}
