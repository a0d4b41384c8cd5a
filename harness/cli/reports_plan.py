"""What ``make reports`` will run: per study, the quick profile's runs, those already
finished in the store by this trainer (its fingerprint: runs of older code are run again,
``study run --rerun-stale``), and the expected time of the rest.

    python -m harness.cli.reports_plan [--profile quick] [--jobs N] [--seconds-per-run S] [--todo FILE]

A study the store has no current runs of is current when its committed report
(``reports/NAME/runs.csv``) holds every planned run, each finished or diverged under this
trainer fingerprint: then nothing is run for it (``report.currency.plan_frame``).

The expected time is the one the README's table and a stale report's first lines give: the
quick runs an hour measured for this machine's vector ISA, ``--jobs`` at a time (2, as
``make reports`` runs them), times the studies' mix (``harness.spec.throughput``); or
``--seconds-per-run`` wall seconds a run, one at a time, when given. Reads the store only;
prints one line per study, one per study whose mean claims run until decided (its rounds and
worst case: ``sequential_lines``) and the total, and with ``--todo`` writes the names of the studies
that have runs to do into FILE (one per line), so that ``make reports`` starts no
``study run`` for a complete study.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from harness.report.currency import plan_frame
from harness.spec.study_schema import jobs_speedup
from harness.spec.throughput import MEASURED_JOBS, estimate


def seconds(runs: int, jobs: int, seconds_per_run: float | None = None) -> tuple[float, str]:
    """Expected wall seconds of ``runs`` quick runs ``jobs`` at a time, and where that comes from."""
    if seconds_per_run is not None:
        return runs * seconds_per_run / jobs_speedup(jobs), f"{seconds_per_run:.0f} s a run as given; --jobs {jobs}"
    est = estimate(runs, jobs)
    return est.seconds, est.rate_text()


def sequential_lines(studies: list[str], profile: str) -> list[str]:
    """One line per study whose ``profile`` runs its mean claims until decided: the claims, the
    most rounds, the looks and the worst case (``study decide``); ``make reports`` runs the full
    plan (every instance: the study's fixed-n claims need them all), and each sequential claim
    reads its first looks' instances (docs/sequential.md)."""
    from harness.report.sequential_rows import design_of
    from harness.spec.study_files import list_studies, load_register, load_study
    from harness.spec.study_schema import plural

    register, out = load_register(), []
    for name in [s for s in studies if s in set(list_studies())]:
        d = design_of(load_study(name), register, profile=profile)
        if d is None:
            continue
        looks = ", ".join(map(str, d.claims[0].plan.schedule()))
        unit = "fresh instances" if d.claims[0].fresh else "runs per arm"
        out.append(f"  {name}: {plural(len(d.claims), 'mean claim')} until decided, at most {plural(d.rounds(), 'round')}"
                   f" (looks at {looks} {unit}), worst case {d.worst_case()} of its runs")
    return out


def main(argv: list[str] | None = None) -> int:
    """Print the plan and the expected total time."""
    from ftgspp.errors import InputError, exit_on_input_error

    ap = argparse.ArgumentParser(prog="python -m harness.cli.reports_plan", description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="quick")
    ap.add_argument("--jobs", type=int, default=MEASURED_JOBS, help="parallel runs per study (make reports: 2)")
    ap.add_argument("--seconds-per-run", type=float, default=None,
                    help="wall seconds a run, one at a time (default: the rate measured for this CPU)")
    ap.add_argument("--todo", type=Path, default=None, help="write the studies with runs to do here")
    args = ap.parse_args(argv)
    try:
        plan = plan_frame(args.profile)
    except InputError as err:
        exit_on_input_error(err)
    for r in plan.itertuples():
        where = "  (current: its committed report)" if r.source == "committed report" else ""
        secs, _ = seconds(r.to_run, args.jobs, args.seconds_per_run)
        print(f"  {r.study:15s} {r.planned:4d} runs, {r.finished:4d} finished, {r.to_run:4d} to run"
              f"  ~{secs / 60:6.1f} min{where}")
    for line in sequential_lines(list(plan.study), args.profile):
        print(line)
    if args.todo is not None:
        args.todo.write_text("".join(f"{r.study}\n" for r in plan.itertuples() if r.to_run > 0))
    todo = int(plan.to_run.sum())
    total, source = seconds(todo, args.jobs, args.seconds_per_run)
    print(f"expected: {todo} of {int(plan.planned.sum())} runs to do, ~{total / 3600:.1f} h ({source}),"
          " then every report and reports/index.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
