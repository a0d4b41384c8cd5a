"""The ``study`` command: list, run, status and report the paper's studies.

    study list
    study run NAME [--profile quick|paper|smoke] [--seeds N] [--scenes A,B] [--variants A,B]
                   [--jobs N] [--launcher basic|joblib|local|slurm] [--lease SECONDS] [--no-wait]
                   [key=value overrides ...]
    study status NAME [same selection options]
    study report NAME [same selection options] [--out DIR]   (default outputs/reports/NAME)
    study budget --preset P | --data DIR [--start N --max N --sesoi DB --seeds N --metric M
                 --noise-sd SD --control] [overrides]
    study check NAME [--reference runs.csv] [--strict]   same training bits as a committed report, or why not
    study index [--out DIR] [--profile P]  OUT/index.md: every study's claims with verdicts
    study decide NAME [--profile P] [--spending obf|pocock] [--until-decided]  runs until decided (docs/sequential.md)

Studies live in ``studies/NAME.yaml``. Runs are tracked in MLflow (``sqlite:///mlflow.db``
in the working directory unless ``MLFLOW_TRACKING_URI`` or ``tracking.uri=`` says
otherwise); ``status`` and ``report`` without selection options use the latest ``run``
invocation of the study. Several ``study run`` invocations (nodes, array jobs, a second
one by hand) may share one tracking server: each run is claimed with a lease first
(``harness.run.lease``), and ``status`` lists the runs in progress with their host and age.
Bad input (unknown study, variant or scene, bad override, a malformed or unreachable tracking
store) prints one line and exits 2 before anything is written. ``study run`` exits 0 only when
every planned run is finished (or failed with a reason), 3 when another live invocation holds
runs (``--no-wait``; else it waits for them), 4 when runs are left without a final record, and
128 + N when signal N (Ctrl-C, SIGTERM, SIGHUP) stopped it, after one line naming the command that
resumes (``run.completion``, ``run.stopping``).
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import gc
import os
import sys
from pathlib import Path

from ftgspp.errors import InputError, exit_on_input_error
from harness.report import COMMITTED_REPORTS, USER_REPORTS
from harness.run.completion import EXIT_HELD, EXIT_STATUSES
from harness.run.launchers import LAUNCHERS, default_jobs
from harness.spec.metrics import budget_metrics
from harness.spec.runs import Selection
from harness.spec.study_schema import JOBS_SPEEDUP, PROFILES, plural


class _Parser(argparse.ArgumentParser):
    """argparse that reports a usage error as one line and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        print(f"error: {self.prog}: {message} (see study --help)", file=sys.stderr)
        raise SystemExit(2)


def _csv(text: str) -> list[str]:
    return [t for t in text.split(",") if t]


def _scenes(text: str) -> list[str]:
    """``--scenes``: names, and ranges of a scene's instances (``studio@11..20``: spec.instances)."""
    from harness.spec.instances import expand_ranges

    return expand_ranges(_csv(text))


def _selection_args(p: argparse.ArgumentParser, name_optional: bool = False) -> None:
    if name_optional:
        p.add_argument("name", nargs="?", default=None,
                       help="study name (study list) or a study file's path (path/to/mine.yaml); none with --all")
    else:
        p.add_argument("name", help="study name (study list) or a study file's path (path/to/mine.yaml)")
    p.add_argument("--profile", choices=PROFILES, default=None, help="quick (default), paper or smoke")
    p.add_argument("--seeds", type=int, default=None, help="number of seeds (default: the profile's)")
    p.add_argument("--scenes", type=_scenes, action="extend", default=[],
                   help="comma-separated subset of scenes; studio@11..20 names instances 11 to 20 of studio")
    p.add_argument("--variants", type=_csv, action="extend", default=[], help="comma-separated subset of variants")
    p.add_argument("overrides", nargs="*", help="Hydra overrides for every run, e.g. iterations=500")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="study", description=__doc__.split("\n\n")[0],
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    sub.add_parser("list", help="the studies, their questions and run counts")
    run = sub.add_parser("run", help="run the missing or failed runs of a study",
                         description="Run the missing or failed runs of a study; finished runs are skipped, so running"
                                     " the same command again resumes. A run another live invocation holds is waited"
                                     " for (--no-wait: not). Ctrl-C, SIGTERM and SIGHUP stop it: the runs in progress"
                                     " are recorded KILLED with the signal and the last line is the command that"
                                     " resumes.",
                         epilog=EXIT_STATUSES, formatter_class=argparse.RawDescriptionHelpFormatter)
    _selection_args(run)
    run.add_argument("--jobs", type=int, default=None,
                     help="parallel runs (Hydra joblib launcher); default: the profile's `jobs` (2 in the quick"
                          f" profiles: {JOBS_SPEEDUP}x the throughput of 1 job on 2 cores, BENCHMARKS.md),"
                          " at most one per core; with --launcher local the most runs at once (default: one per"
                          " core, as many as fit in the available memory)")
    run.add_argument("--launcher", choices=LAUNCHERS, default="basic",
                     help="basic (default), joblib, local (submitit) or slurm (submitit; conf/hydra/launcher/slurm.yaml)")
    run.add_argument("--rerun-stale", action="store_true",
                     help="run again every finished run that another trainer version made (trainer fingerprint,"
                          " harness/tracking/provenance.py); make reports uses it")
    run.add_argument("--lease", type=float, default=None, metavar="SECONDS",
                     help="a claimed run is taken over after this long without a heartbeat"
                          " (default $FTGSPP_LEASE_S or 300); at once when its holder process on this host is gone")
    run.add_argument("--no-wait", action="store_true",
                     help="do not wait for runs that another live invocation holds: run the rest, name each held run's"
                          f" holder (host, pid) and lease expiry, and exit with status {EXIT_HELD}")
    status = sub.add_parser("status", help="done / failed / missing runs per variant, scene and seed")
    _selection_args(status)
    report = sub.add_parser("report", help="tables and plots into OUT/NAME/ (NAME --all: every study)")
    _selection_args(report, name_optional=True)
    report.add_argument("--out", type=Path, default=USER_REPORTS,
                        help=f"reports root (default: {USER_REPORTS}; the committed reports/ is written only by"
                             " `make reports`)")
    report.add_argument("--all", action="store_true", help="every study, in one process (no NAME)")
    report.add_argument("--if-changed", action="store_true",
                        help="skip a report whose runs and code are those it was made from (reports/NAME/.fingerprint)")
    measure = sub.add_parser("measure", help="render FPS (1 thread, all cores) and size of each finished run's"
                                             " trained model, logged to its run; run it with nothing else running")
    _selection_args(measure)
    measure.add_argument("--force", action="store_true", help="measure runs that already have the figures again")
    check = sub.add_parser("check", help="compare the study's runs with a committed report's runs.csv, bit for bit:"
                                         " training identical, evaluation differs, expected to differ (another"
                                         " determinism domain or config) or differs unexpectedly")
    _selection_args(check)
    check.add_argument("--reference", type=Path, default=None,
                       help=f"the runs.csv to compare with (default: {COMMITTED_REPORTS}/NAME/runs.csv)")
    check.add_argument("--strict", action="store_true",
                       help="exit 1 when a run differs unexpectedly (or no run could be compared)")
    budget = sub.add_parser("budget", help="the smallest Gaussian budget a scene needs (doubling, then bisection)")
    where = budget.add_mutually_exclusive_group(required=True)
    where.add_argument("--preset", help="a built-in synthetic scene (ftgspp synth presets, or known_size: K = 500"
                                        " Gaussians and sensor noise, harness/run/known_size.py)")
    where.add_argument("--data", help="a scene folder of yours")
    budget.add_argument("--start", type=int, default=500, help="first budget (default 500)")
    budget.add_argument("--max", type=int, default=64_000, help="largest budget to try (default 64000)")
    budget.add_argument("--sesoi", "--threshold", type=float, default=None,
                        help="dB within the best that count as as good (default: the metric's SESOI, 0.2 dB)")
    budget.add_argument("--noise-sd", type=float, default=None,
                        help="known_size: sensor noise SD in 8-bit units (default 2; 0: the noise-free scene)")
    budget.add_argument("--control", action="store_true",
                        help="known_size: also train K Gaussians started from the true ones (init.matcher=known)")
    budget.add_argument("--seeds", type=int, default=3, help="runs per budget (default 3)")
    budget.add_argument("--metric", choices=budget_metrics(), default="psnr",
                        help="what a doubling must gain: held-out PSNR (psnr, default) or colour-aligned (psnr_cc),"
                             " which leaves out the held-out camera's colour no budget can learn")
    budget.add_argument("--jobs", type=int, default=None, help="parallel runs (default: one per core, at most 2)")
    budget.add_argument("--out", type=Path, default=USER_REPORTS / "budget", help="where the result goes")
    budget.add_argument("overrides", nargs="*", help="Hydra overrides for every run, e.g. model=ftgspp")
    from harness.cli.prune_study import add_parser as add_prune

    add_prune(sub, _selection_args, USER_REPORTS)
    from harness.cli.decide import add_parser as add_decide

    add_decide(sub)
    index = sub.add_parser("index", help="index.md: one row per claim of every study with runs")
    index.add_argument("--out", type=Path, default=USER_REPORTS, help=f"reports root (default: {USER_REPORTS})")
    index.add_argument("--profile", choices=PROFILES, default=None,
                       help="decide every study over all of this profile's runs (default: each study's latest invocation)")
    return parser


def _selection(args: argparse.Namespace, required: bool) -> Selection | None:
    given = args.profile or args.seeds is not None or args.scenes or args.variants or args.overrides
    if not given and not required:
        return None
    return Selection(profile=args.profile or "quick", seeds=args.seeds, scenes=list(args.scenes),
                     variants=list(args.variants), overrides=list(args.overrides))


def cmd_run(args: argparse.Namespace, argv: list[str]) -> int:
    """``study run``: its exit status is ``run.completion``'s; a stop (Ctrl-C, SIGTERM, SIGHUP)
    ends with one line - what was recorded and the command that resumes - and 128 + the signal."""
    import shlex

    from harness.run import stopping
    from harness.run.runner import run_study

    try:
        with stopping.on_signals():  # from here on, not only once the runner has started
            sel = _selection(args, required=True)
            jobs = default_jobs(args.name, sel.profile, args.launcher) if args.jobs is None else args.jobs
            outcome = run_study(args.name, sel, jobs=jobs, launcher=args.launcher, lease_s=args.lease,
                                rerun_stale=args.rerun_stale, wait=not args.no_wait)
    except KeyboardInterrupt as exc:
        stop = stopping.as_stopped(exc)
        with contextlib.suppress(OSError):  # after SIGHUP the terminal may be gone; the store has the record
            print(f"stopped by {stop.name}: {plural(stop.finished, 'run')} finished, {stop.killed} recorded KILLED"
                  f" (stop_signal={stop.name}); resume with: {shlex.join(['study', *argv])}", flush=True)
        return stop.exit_status
    # at exit, after the workers have stopped: the interpreter's last collection would walk
    # every object of this process (about 0.3 s here; run.heap does the same for workers)
    atexit.register(gc.freeze)
    return getattr(outcome, "exit_status", 0)  # (test_study_cli stubs run_study with one returning None)


def cmd_list() -> int:
    from harness.spec.runs import Selection, describe_runs, expand
    from harness.spec.study_files import list_studies, load_study

    for name in list_studies():
        s = load_study(name)
        print(f"{name}: {s.question}")
        for prof in (p for p in ("quick", "paper") if p in s.profiles):
            p = s.profiles[prof]
            runs = expand(s, Selection(profile=prof))
            print(f"    {prof:5s}: {describe_runs(runs)}; {p.estimate(len(runs), p.jobs)}")
        first = s.profiles.get("quick") or next(iter(s.profiles.values()))
        print(f"    run: {first.command or f'study run {name} --profile {first.name}'}")
    return 0


def cmd_status(args: argparse.Namespace) -> int:
    import pandas as pd

    from harness.analysis import aggregate
    from harness.report.results import collect

    data = collect(args.name, _selection(args, required=False))
    df = data.df
    print(f"{args.name} ({data.sel.profile}): {len(df)} runs in {data.experiment} at {data.uri}")
    # spec.instances: how many instances of each scene (as the study file writes it) the runs are on
    spans = df.groupby("instance_of", sort=False).instance.nunique() if "instance_of" in df else pd.Series(dtype=int)
    if (spans > 1).any():
        print("  scene instances: " + ", ".join(f"{s} ({k})" for s, k in spans.items()))
    width = max(len("variant"), *(len(v) for v in df.variant))
    swidth = max(len("scene"), *(len(s) for s in df.scene))
    print(f"  {'variant':{width}s}  {'scene':{swidth}s}  done  failed  missing  detail")
    for (v, s), sub in df.groupby(["variant", "scene"], sort=False):
        done = int((sub.status == "FINISHED").sum())
        failed = sub[sub.status.isin(["FAILED", "KILLED"])]
        missing = sub[sub.status.isin(["MISSING", "RUNNING"])]
        detail = []
        doms = sorted(set(sub[sub.status == "FINISHED"].get("domain", pd.Series(dtype=str)).dropna()) - {""})
        if len(doms) > 1:
            detail.append(f"MIXED determinism domains {', '.join(doms)}")
        if len(failed):
            detail.append("failed seeds " + ", ".join(f"{r.seed}" + (f" ({r.failure})" if r.failure else "")
                                                       for r in failed.itertuples()))
        if len(missing):
            detail.append("missing seeds " + ", ".join(str(x) for x in missing.seed))
        print(f"  {v:{width}s}  {s:{swidth}s}  {done:4d}  {len(failed):6d}  {len(missing):7d}  {'; '.join(detail)}")
    done = int((df.status == "FINISHED").sum())
    failed = int(df.status.isin(["FAILED", "KILLED"]).sum())
    running = _print_running(data.uri, data.experiment, args.name)
    print(f"total: {done} done, {failed} failed, {len(df) - done - failed} missing"
          + (f"; {running} running now (listed above)" if running else ""))
    doms = aggregate.domains(df)
    if len(doms):
        print("determinism domains: " + "; ".join(f"{d.domain} ({d['mode']} mode, torch kernels {aggregate.kernel_set(d.cpu_capability)}, {d.runs} runs)"
                                                 for _, d in doms.iterrows()))
    return 0


def cmd_budget(args: argparse.Namespace) -> int:
    """``study budget``: search, then write and print the answer."""
    from harness.cli.budget import data_scene, search, synthetic_scene
    from harness.report.budget_page import answer, write

    if args.start < 1 or args.max < args.start or args.seeds < 2 or (args.sesoi is not None and args.sesoi <= 0):
        raise InputError("study budget", "needs 1 <= --start <= --max, --seeds >= 2 and --sesoi > 0")
    if (args.noise_sd is not None and args.noise_sd < 0) or (args.control and args.preset != "known_size"):
        raise InputError("study budget", "--noise-sd >= 0, and --control only with --preset known_size")
    scene = synthetic_scene(args.preset, args.noise_sd) if args.preset else data_scene(args.data)
    true_size = None
    if args.preset == "known_size":  # a known-size scene says how many Gaussians drew it
        from harness.spec.known_scene import resolve

        true_size = resolve({k: v for k, v in scene.synth.items() if k != "preset"}).k
    jobs = args.jobs or max(1, min(2, os.cpu_count() or 1))
    found = search(scene, start=args.start, max_budget=args.max, sesoi=args.sesoi, seeds=args.seeds,
                   overrides=list(args.overrides), jobs=jobs, metric=args.metric,
                   control=true_size if args.control else None)
    where = f"--preset {args.preset}" if args.preset else f"--data {args.data}"
    if args.preset == "known_size":
        where += f" --noise-sd {scene.synth.get('noise_sd', 0):g}" + (" --control" if args.control else "")
    command = " ".join([f"study budget {where} --start {args.start} --max {args.max} --seeds {args.seeds}",
                        f"--sesoi {found.sesoi:g} --metric {args.metric} --out {args.out}", *args.overrides])
    path = write(found, args.out / found.scene, true_size, command)
    print(answer(found, true_size))
    print(f"report: {path}")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    """``study check NAME``: the latest invocation's runs against a committed report, each run
    classified (``analysis.reproduction``); ``reproduction.csv`` has one row per run."""
    from harness.analysis import reproduction
    from harness.report.results import collect

    reference = args.reference or COMMITTED_REPORTS / args.name / "runs.csv"
    if not reference.is_file():
        raise InputError(str(reference), "no such runs.csv (give --reference PATH)")
    data = collect(args.name, _selection(args, required=False))
    committed = reproduction.read_reference(str(reference))
    frame = reproduction.compare(data.df, committed)
    out = USER_REPORTS / args.name
    out.mkdir(parents=True, exist_ok=True)
    frame.to_csv(out / "reproduction.csv", index=False)
    for line in reproduction.summary(frame, str(reference)):
        print(line)
    print(f"the committed runs were made on {reproduction.hosts(committed)}; these on {reproduction.hosts(data.df)}")
    print(f"per run: {out / 'reproduction.csv'}")
    return 1 if args.strict and reproduction.strict_failure(frame) else 0


def _print_running(uri: str, experiment: str, study: str) -> int:
    """List the study's RUNNING child runs with their host, age and lease state."""
    import time

    from harness.run import lease
    from harness.tracking.records import load_runs, open_store

    now = time.time()
    runs = [r for r in load_runs(open_store(uri), experiment, study) if r.status == "RUNNING"]
    for rec in runs:
        state = "live" if lease.is_live(rec, now=now) else "stale: the next `study run` takes it over"
        age = now - rec.start_time / 1000.0
        print(f"  running: {rec.tags.get('mlflow.runName', rec.run_id)} on {rec.tags.get(lease.OWNER, 'unknown host')},"
              f" started {age:.0f}s ago, heartbeat {lease.heartbeat_age(rec, now):.0f}s ago ({state})")
    return len(runs)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``study`` console script."""
    parser = build_parser()
    # overrides may come after options too (argparse would have consumed the positional early)
    args, extra = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    if extra and (args.command in ("list", "index", "decide") or any(e.startswith("-") for e in extra)):
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if extra:
        args.overrides = [*args.overrides, *extra]
    try:
        if getattr(args, "name", None):  # a study file anywhere: `study run path/to/mine.yaml`
            from harness.spec.study_files import use_study_file

            args.name = use_study_file(args.name)
        if args.command == "list":
            return cmd_list()
        if args.command == "run":
            return cmd_run(args, sys.argv[1:] if argv is None else argv)
        if args.command == "status":
            return cmd_status(args)
        if args.command == "report":
            from harness.report.writer import write_report
            from harness.spec.study_files import list_studies

            if args.all == bool(args.name):
                raise InputError("study report", "give a study name or --all (not both)")
            for name in list_studies() if args.all else [args.name]:
                write_report(name, _selection(args, required=False), reports_root=args.out, if_changed=args.if_changed,
                             skip_empty=args.all)
            return 0
        if args.command == "budget":
            return cmd_budget(args)
        if args.command == "check":
            return cmd_check(args)
        if args.command == "prune":
            from harness.cli.prune_study import cmd_prune

            return cmd_prune(args, _selection(args, required=True), sys.argv[1:] if argv is None else argv)
        if args.command == "decide":
            from harness.cli.decide import cmd_decide

            return cmd_decide(args, sys.argv[1:] if argv is None else argv)
        if args.command == "measure":
            from harness.cli.measure import measure_study

            measure_study(args.name, _selection(args, required=False), force=args.force)
            return 0
        if args.command == "index":
            from harness.report.index import write_claims_index

            write_claims_index(args.out, profile=args.profile)
            return 0
    except InputError as err:
        exit_on_input_error(err)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
