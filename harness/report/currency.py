"""Are a report's numbers this checkout's, and what does refreshing them take?

A report is current when every run it counts was made by this checkout's trainer
(``tracking.provenance.checkout_fingerprint``) or by one recorded to train the same bits
(``tracking.provenance.same_bits``). A stale one says so in the first lines after
its title (``stale_note``): which trainer made its runs, which this checkout has, the command
that refreshes it and that command's expected time on this machine (``spec.throughput``: the
rates the README's table and ``harness.cli.reports_plan`` use). A current one says nothing.

``plan_frame`` is what ``make reports`` will run (``harness.cli.reports_plan`` prints it): per
study, the quick profile's runs, those already finished in the store by this trainer (runs of
older code are run again, ``study run --rerun-stale``) and the rest (``to_do``). A study the
store has no current runs of is current when its committed report (``reports/NAME/runs.csv``)
holds every planned run (same variant, scene, seed and config hash), each finished or diverged
under this trainer fingerprint: then nothing is run for it and its report stays as committed.
So a fresh clone whose reports were made by its own trainer runs nothing, and after a change
only the studies it touches run again.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from harness.analysis.reproduction import KEY as RUN_KEY, answered
from harness.report import COMMITTED_REPORTS
from harness.spec.study_schema import ProfileSpec
from harness.spec.throughput import estimate

KEY = [*RUN_KEY, "config_hash"]  # one planned run: the key study check matches runs by, and its config
QUICK = "quick"  # the profile `make reports` runs, whose rate spec.throughput has


def to_do(df: pd.DataFrame, trainer: str) -> int:
    """Runs of the per-run frame ``df`` that refreshing runs: all but those FINISHED by ``trainer``
    (or a trainer recorded to train the same bits)."""
    from harness.tracking.provenance import same_bits

    if not len(df):
        return 0
    made_by = df["trainer_fingerprint"] if "trainer_fingerprint" in df else pd.Series("", index=df.index)
    return int(len(df) - ((df.status == "FINISHED") & made_by.isin(same_bits(trainer))).sum())


def expected(runs: int, profile: str, prof: ProfileSpec | None, jobs: int) -> str:
    """How long ``runs`` runs of ``profile`` take ``jobs`` at a time: from the measured quick-run
    rates (``spec.throughput``) for the quick profile, else from the profile's ``run_seconds``."""
    if profile == QUICK or prof is None:
        return estimate(runs, jobs).text()
    return prof.estimate(runs, jobs)


def stale_note(made_by: list[str], current: str, refresh: str, runs: int, when: str) -> list[str]:
    """The Markdown lines a stale page opens with; none when every run was made by ``current`` (or
    a trainer recorded to train the same bits)."""
    from harness.tracking.provenance import all_current

    if not made_by or all_current(made_by, current):
        return []
    trainers = ", ".join(f"`{f}`" for f in made_by)
    return [f"**Stale: these numbers are not this checkout's.** Their runs were made by trainer {trainers};"
            f" this checkout's trainer is `{current}` (harness/tracking/provenance.py), and its code need not give"
            f" the same numbers. Refresh them with `{refresh}`: {runs} runs to do, {when}.", ""]


def committed_current(df: pd.DataFrame, committed: Path, trainer: str) -> bool:
    """Whether the report's ``runs.csv`` at ``committed`` holds every run of the plan ``df``,
    finished or diverged, made by ``trainer`` or a trainer recorded to train the same bits (a
    recorded divergence is that code's result)."""
    from harness.tracking.provenance import same_bits

    if not committed.is_file() or not len(df) or not set(KEY) <= set(df.columns):
        return False
    runs = pd.read_csv(committed, dtype={"config_hash": str, "trainer_fingerprint": str})
    if not set(KEY) | {"status", "trainer_fingerprint"} <= set(runs.columns):
        return False
    ok = runs[runs.trainer_fingerprint.isin(same_bits(trainer)) & answered(runs)]
    have = set(ok[KEY].astype(str).itertuples(index=False, name=None))
    return all(key in have for key in df[KEY].astype(str).itertuples(index=False, name=None))


def plan_frame(profile: str = QUICK, reports_root: Path = COMMITTED_REPORTS, studies_dir: Path | None = None,
               trainer: str | None = None) -> pd.DataFrame:
    """One row per study: planned, finished and missing runs, and where the finished runs are
    (``source``: the tracking store, or the committed report). ``trainer``: this checkout's
    fingerprint unless given."""
    from harness.report.results import collect
    from harness.spec.runs import Selection
    from harness.spec.study_files import list_studies
    from harness.tracking.provenance import trainer_fingerprint

    current = trainer or trainer_fingerprint()
    rows = []
    for name in list_studies(studies_dir):
        df = collect(name, Selection(profile=profile), studies_dir).df
        n_todo, source = to_do(df, current), "store"
        if n_todo == len(df) and committed_current(df, Path(reports_root) / name / "runs.csv", current):
            n_todo, source = 0, "committed report"
        rows.append({"study": name, "planned": len(df), "finished": len(df) - n_todo, "to_run": n_todo,
                     "source": source})
    return pd.DataFrame(rows)
