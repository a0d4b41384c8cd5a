"""What ``make reports`` will run: per study, the quick profile's runs, those already
finished in the store by this trainer (its fingerprint: runs of older code are run again,
``study run --rerun-stale``), and the expected time of the rest.

    python -m harness.cli.reports_plan [--profile quick] [--seconds-per-run S] [--jobs N] [--todo FILE]

A study the store has no current runs of is current when its committed report
(``reports/NAME/runs.csv``) holds every planned run (same variant, scene, seed and config
hash), each finished or diverged under this trainer fingerprint: then nothing is run for it and
its report stays as committed. So a fresh clone whose reports were made by its own trainer
runs nothing, and after a change only the studies it touches run again.

The time per run is the median ``train_seconds`` of the finished runs in the store times
``OVERHEAD`` (evaluation, diagnostics, start-up), or ``--seconds-per-run`` when the store
has none. Reads the store only; prints one line per study and the total, and with ``--todo``
writes the names of the studies that have runs to do into FILE (one per line), so that
``make reports`` starts no ``study run`` for a complete study.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import pandas as pd

from harness.analysis.reproduction import KEY as RUN_KEY
from harness.report import COMMITTED_REPORTS
from harness.spec.study_schema import jobs_speedup

OVERHEAD = 1.45  # wall time of a run / its train_seconds (evaluation, diagnostics, logging): ~12 s on ~26 s


KEY = [*RUN_KEY, "config_hash"]  # one planned run: the key study check matches runs by, and its config


def committed_current(df: pd.DataFrame, committed: Path, trainer: str) -> bool:
    """Whether the report's ``runs.csv`` at ``committed`` holds every run of the plan ``df``,
    finished or diverged, made by ``trainer`` (a recorded divergence is that code's result)."""
    if not committed.is_file() or not len(df) or not set(KEY) <= set(df.columns):
        return False
    runs = pd.read_csv(committed, dtype={"config_hash": str, "trainer_fingerprint": str})
    if not set(KEY) | {"status", "trainer_fingerprint"} <= set(runs.columns):
        return False
    failure = runs["failure"] if "failure" in runs else pd.Series("", index=runs.index)
    ok = runs[(runs.trainer_fingerprint == trainer)
              & ((runs.status == "FINISHED") | ((runs.status == "FAILED") & (failure == "diverged")))]
    have = set(ok[KEY].astype(str).itertuples(index=False, name=None))
    return all(key in have for key in df[KEY].astype(str).itertuples(index=False, name=None))


def plan_frame(profile: str = "quick", reports_root: Path = COMMITTED_REPORTS) -> pd.DataFrame:
    """One row per study: planned, finished and missing runs, median train seconds, and where
    the finished runs are (``source``: the tracking store, or the committed report)."""
    from harness.report.results import collect
    from harness.spec.runs import Selection
    from harness.spec.study_files import list_studies
    from harness.tracking.provenance import trainer_fingerprint

    current = trainer_fingerprint()
    rows = []
    for name in list_studies():
        df = collect(name, Selection(profile=profile)).df
        done = df[(df.status == "FINISHED") & (df.get("trainer_fingerprint", pd.Series(dtype=str)) == current)]
        secs = float(done["train_seconds"].median()) if "train_seconds" in done and len(done) else math.nan
        n_done, source = len(done), "store"
        if n_done == 0 and committed_current(df, Path(reports_root) / name / "runs.csv", current):
            n_done, source = len(df), "committed report"
        rows.append({"study": name, "planned": len(df), "finished": n_done, "to_run": len(df) - n_done,
                     "median_train_seconds": secs, "source": source})
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    """Print the plan and the expected total time."""
    from ftgspp.errors import InputError, exit_on_input_error

    ap = argparse.ArgumentParser(prog="python -m harness.cli.reports_plan", description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="quick")
    ap.add_argument("--seconds-per-run", type=float, default=120.0, help="when the store has no finished run")
    ap.add_argument("--jobs", type=int, default=1, help="parallel runs per study")
    ap.add_argument("--todo", type=Path, default=None, help="write the studies with runs to do here")
    args = ap.parse_args(argv)
    try:
        plan = plan_frame(args.profile)
    except InputError as err:
        exit_on_input_error(err)
    measured = plan.median_train_seconds.dropna()
    per_run = float(measured.median()) * OVERHEAD if len(measured) else args.seconds_per_run
    source = "median of finished runs x %.1f" % OVERHEAD if len(measured) else "assumed (no finished runs yet)"
    for r in plan.itertuples():
        where = "  (current: its committed report)" if r.source == "committed report" else ""
        print(f"  {r.study:15s} {r.planned:4d} runs, {r.finished:4d} finished, {r.to_run:4d} to run"
              f"  ~{r.to_run * per_run / jobs_speedup(args.jobs) / 60:6.1f} min{where}")
    if args.todo is not None:
        args.todo.write_text("".join(f"{r.study}\n" for r in plan.itertuples() if r.to_run > 0))
    total = plan.to_run.sum() * per_run / jobs_speedup(args.jobs)
    print(f"expected: {int(plan.to_run.sum())} of {int(plan.planned.sum())} runs to do, ~{total / 3600:.1f} h"
          f" ({per_run:.0f} s per run, {source}; --jobs {args.jobs}), then every report and reports/index.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
