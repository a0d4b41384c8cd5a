"""``study decide NAME [--profile P] [--spending obf|pocock] [--until-decided [--jobs N] [--lease S]]``.

Runs until decided (issue 57; docs/sequential.md): prints the study's sequential plan under the
profile — per counted mean claim its looks, its cap in runs and CPU hours at the profile's
``run_seconds``, the study's worst case — then, per family and claim, what the runs so far decide
(``analysis.sequential_study``: the rounds replayed from the runs, no state kept anywhere):
**decided** (which hypothesis, the verdict), **continue** (the runs its next look needs and what
they are) or **stop at cap** (the runs a fixed design would need at its α share, their CPU hours,
and the command that would run them on a cluster); last, the one ``study run`` command that adds
the next round. The runs are the tracking store's, else the committed ``reports/NAME/runs.csv``.

``--until-decided`` loops: decide, run the next round in this process as ``study run`` does
(``run.runner.run_study``: finished runs skipped, leases, waiting for runs other invocations
hold), decide again — until no claim continues, or before a round that would take the study's
runs beyond ``study_cap_cpu_hours``. Each round's parent run is tagged ``sequential.round``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import shlex
from collections.abc import Callable
from typing import Any

from ftgspp.errors import InputError
from harness.analysis import sequential as Q, sequential_study as S, stats
from harness.spec.study_schema import PROFILES, plural

SPENDINGS = tuple(S.SPENDING_NAMES)
Echo = Callable[[str], None]


def add_parser(sub: Any) -> None:
    """Register ``study decide`` on the ``study`` parser's subparsers."""
    p = sub.add_parser("decide", help="runs until decided: what each mean claim's runs decide, and the next round",
                       description=__doc__.split("\n\n")[1])
    p.add_argument("name", help="study name (study list) or a study file's path (path/to/mine.yaml)")
    p.add_argument("--profile", choices=PROFILES, default="quick", help="quick (default), paper or smoke")
    p.add_argument("--spending", choices=SPENDINGS, default="obf",
                   help="α-spending: obf (O'Brien–Fleming, default) or pocock; fix it before the first round")
    p.add_argument("--until-decided", action="store_true",
                   help="run round after round until no claim continues or the study's CPU-hour cap would be passed")
    p.add_argument("--jobs", type=int, default=None, help="parallel runs of a round (default: the profile's `jobs`)")
    p.add_argument("--lease", type=float, default=None, metavar="SECONDS", help="as `study run --lease`")


def cmd_decide(args: argparse.Namespace, argv: list[str], echo: Echo = print) -> int:
    """``study decide``: the plan, then the decisions (once, or round after round)."""
    from harness.spec.study_files import list_studies, load_register, load_study

    if not args.until_decided and (args.jobs is not None or args.lease is not None):
        raise InputError("study decide", "--jobs and --lease go with --until-decided")
    study = load_study(args.name)
    d = S.design(study, args.profile, load_register(),
                 lambda: {n: load_study(n) for n in list_studies() if n != study.name})
    for line in plan_lines(d, args.spending):
        echo(line)
    if not args.until_decided:
        data, _ = read_runs(d, echo)
        families = S.decide(d, data.df, spending=args.spending)
        for line in decision_lines(d, families, data.df):
            echo(line)
        return 0
    return until_decided(d, args, argv, echo)


def read_runs(d: S.Design, echo: Echo) -> tuple[Any, str]:
    """(the runs every sequential claim may use, from the tracking store or else the committed
    ``runs.csv``; the tracking store's URI, where a round's runs go)."""
    from harness.report import COMMITTED_REPORTS, committed
    from harness.report.results import collect
    from harness.tracking.store import display_uri

    data = collect(d.study.name, S.selection(d))
    store = data.uri
    if not (data.df.status == "FINISHED").any():
        with contextlib.suppress(InputError):  # before the first round there are no runs anywhere
            data = committed.from_committed(data, COMMITTED_REPORTS / d.study.name, echo=lambda line: None)
    if data.recorded is not None:
        echo(f"runs: {(data.recorded.folder / 'runs.csv').as_posix()} (the tracking store has none of them)")
    else:
        echo(f"runs: {int((data.df.status == 'FINISHED').sum())} finished in {data.experiment} at {display_uri(store)}")
    return data, store


# --------------------------------------------------------------------------- what it prints


def _hours(d: S.Design, runs: float) -> str:
    h = d.hours(runs) if math.isfinite(runs) else math.nan
    return f"{h:.3g} CPU h" if math.isfinite(h) else "CPU hours unknown (no run_seconds)"


def _what(c: S.SeqClaim) -> str:
    spec = c.spec
    return f"{spec.a} − {spec.b or '0'} in {spec.metric} on {', '.join(spec.scenes)}, {c.unit}"


def plan_lines(d: S.Design, spending: str) -> list[str]:
    """The plan: the rule, each claim's looks and cap, the study's worst case and cap."""
    p = d.profile
    at = f"{p.run_seconds:.0f} s a run on {p.machine}" if d.hours_per_run else "no run_seconds: CPU hours unknown"
    lines = [f"{d.study.name} ({p.name}): runs until decided, {S.SPENDING_NAMES[spending]} spending; {at}"]
    for fam, claims in d.families.items():
        total, alpha = d.shares[fam]
        lines.append(f"  family {fam}: {plural(len(claims), 'claim')} here of {total} that count in it over every"
                     f" study: α {alpha:.3g} of its {stats.ALPHA:g} (one Holm over their difference and equivalence"
                     " hypotheses; the report's fixed-n Holm keeps the rest)")
    lines.append("plan (runs per arm at each look, the claim's cap):")
    for fam, claims in d.families.items():
        for c in claims:
            n = c.plan.n_max
            runs = f" = {plural(n * c.plan.arms, 'run')}" if c.plan.arms > 1 else ""
            lines.append(f"  {fam} / {c.spec.id} ({_what(c)}): looks {', '.join(map(str, c.plan.schedule()))};"
                         f" cap {n} {c.unit}{runs}, {_hours(d, n * c.plan.arms)}")
    cap = f"cap {d.study_cap:g} CPU h" if d.study_cap else "no study cap (study_cap_cpu_hours)"
    lines.append(f"study: at most {plural(d.rounds(), 'round')}; worst case {plural(d.worst_case(), 'run')},"
                 f" {_hours(d, d.worst_case())}; {cap}")
    lines += [f"  not run until decided: {i} ({why})" for i, why in d.left_out]
    return lines


def _decided(o: S.Outcome) -> str:
    dec = o.decision
    assert dec is not None
    names = {"difference": "minimal-effect (|effect| > SESOI)" if o.claim.spec.expect == "equivalent" else
             "difference", "equivalence": "equivalence (TOST within ±SESOI)"}
    which = " and ".join(f"{names[h]} p = {dec.p[Q.HYPOTHESES.index(h)]:.3g}" for h in dec.rejected)
    return f"decided at look {dec.look} ({dec.n} {o.claim.unit}): {which} rejected, {dec.verdict}"


def _continuing(d: S.Design, o: S.Outcome, done: set) -> str:
    c, missing = o.claim, S.missing_cells(o, done)
    head = f"continue: look {(o.decision.look if o.decision else 0) + 1} needs {o.needs} {c.unit}"
    if not missing:
        return head + ", which it has (its family's next round waits for its other claims)"
    scenes = dict.fromkeys(s for _, s, _ in missing) if c.fresh else c.scenes(o.needs)  # the instances it lacks
    return (head + f"; add {plural(len(missing), 'run')} ({', '.join(c.spec.arms())} on"
            f" {', '.join(scenes)}, --seeds {c.seeds(o.needs)}), {_hours(d, len(missing))}")


def _at_cap(d: S.Design, o: S.Outcome) -> str:
    from harness.spec.instances import instance_name
    from harness.spec.runs import Selection, command_line

    dec, c = o.decision, o.claim
    assert dec is not None
    head = f"stop at cap ({dec.n} {c.unit} at look {dec.look}, each open hypothesis at α {dec.share:.3g}): "
    if not math.isfinite(dec.runs_needed):
        why = "its runs show no spread" if math.isnan(dec.runs_needed) else "more than 1000 per arm"
        return head + f"a fixed design's runs cannot be estimated ({why})"
    n = int(dec.runs_needed)
    if c.fresh:  # new instances after those its looks read: a confirmatory design on data it has not seen
        k = math.ceil(n / len(c.spec.scenes))
        scenes = [instance_name(s, i) for i in range(c.fresh + 1, c.fresh + 1 + k) for s in c.spec.scenes][:n]
        sel = Selection(d.profile.name, 1, scenes, list(c.spec.arms()))
        draw = (f", on new instances {c.fresh + 1}–{c.fresh + k} (`instances: {c.fresh + 1 + k}` on"
                f" {', '.join(c.spec.scenes)} in profiles.{d.profile.name})")
    else:
        sel, draw = Selection(d.profile.name, c.seeds(n), list(c.scenes(n)), list(c.spec.arms())), ""
    return head + (f"a fixed design at that share needs {n} {c.unit} (80% power at the SESOI),"
                   f" {_hours(d, n * c.plan.arms)} on {d.profile.machine}; on a cluster{draw}:"
                   f" {command_line(d.study.name, sel, launcher='slurm')}")


def decision_lines(d: S.Design, families: list[S.FamilyReplay], df: Any) -> list[str]:
    """Per family and claim: decided, continue or stop at cap; then the command of the next round."""
    from harness.spec.runs import Selection, command_line

    done = S.finished_runs(df)
    lines = []
    for f in families:
        most = max(len(o.claim.plan.schedule()) for o in f.outcomes)
        lines.append(f"family {f.name}: {plural(len(f.outcomes), 'claim')} (Holm over {2 * len(f.outcomes)}"
                     f" hypotheses), {f.rounds} of at most {plural(most, 'round')} decided")
        for o in f.outcomes:
            text = _continuing(d, o, done) if o.status == Q.CONTINUE else \
                _decided(o) if o.status == Q.DECIDED else _at_cap(d, o)
            if o.status == Q.AT_CAP and any(other.needs for other in f.outcomes):
                text += " (read again at its last look while its family goes on: others' rejections raise its share)"
            lines.append(f"  {o.claim.spec.id}: {text}")
    nxt = S.next_round(d, families, df)
    if nxt is None:
        return [*lines, "every claim is decided or at its cap: nothing more to run"]
    sel = Selection(d.profile.name, nxt.seeds, list(nxt.scenes), list(nxt.variants))
    filler = f"{nxt.own} of them read by the next looks, the rest fill its variants × scenes" \
        if nxt.own < nxt.runs else "all read by the next looks"
    return [*lines, f"next round: {command_line(d.study.name, sel)}", f"  {plural(nxt.runs, 'run')},"
            f" {_hours(d, nxt.runs)}, {filler} (the study's runs so far: {_hours(d, S.spent(d, df))})"]


# --------------------------------------------------------------------------- --until-decided


def until_decided(d: S.Design, args: argparse.Namespace, argv: list[str], echo: Echo) -> int:
    """Decide, run the next round, decide again (module docstring); the exit status of the
    round that failed, 1 when a round added none of the runs its looks need, else 0."""
    from harness.tracking.store import Store

    cap = d.study_cap
    if cap is not None and d.hours_per_run is None:
        raise InputError(f"profiles.{d.profile.name}.sequential.study_cap_cpu_hours",
                         "a CPU-hour cap needs the profile's run_seconds")
    echo(f"until decided: at most {plural(d.rounds(), 'round')}, "
         + (f"stopping before a round that would take the study beyond {cap:g} CPU h" if cap else "no CPU-hour cap"))
    before = None
    while True:
        data, uri = read_runs(d, echo)
        families = S.decide(d, data.df, spending=args.spending)
        for line in decision_lines(d, families, data.df):
            echo(line)
        nxt = S.next_round(d, families, data.df)
        if nxt is None:
            return 0
        progress = [(f.rounds, [o.runs.n for o in f.outcomes]) for f in families]
        if progress == before or nxt.runs == 0:  # its runs failed again, or finished without the claims' metric
            echo(f"stopping: {'the last round added' if progress == before else 'the next round would add'} none of"
                 f" the runs the next looks read (see study status {d.study.name})")
            return 1
        used, more = d.hours(S.spent(d, data.df)), d.hours(nxt.runs)
        if cap is not None and used + more > cap:
            echo(f"stop: the next round ({more:.3g} CPU h) would take the study to {used + more:.3g} CPU h,"
                 f" beyond its cap of {cap:g}")
            return 0
        before = progress
        k = max(f.rounds for f in families if any(o.needs for o in f.outcomes)) + 1
        status, parent = run_round(d, nxt, args, argv, echo)
        if parent:  # the round on the invocation's parent run (its runs are its children)
            looks = {o.claim.spec.id: o.needs for f in families for o in f.outcomes if o.needs}
            Store(uri).log_batch(parent, tags={"sequential.round": str(k), "sequential.looks": json.dumps(looks),
                                               "sequential.spending": args.spending})
        if status != 0:
            return status


def run_round(d: S.Design, nxt: S.Round, args: argparse.Namespace, argv: list[str], echo: Echo) -> tuple[int, str]:
    """(exit status, parent run id) of the round's runs, run as ``study run`` runs them; a stop
    (Ctrl-C, SIGTERM, SIGHUP) prints the command that resumes the loop and gives 128 + the signal."""
    from harness.run.launchers import default_jobs
    from harness.run import stopping
    from harness.run.runner import run_study
    from harness.spec.runs import Selection

    sel = Selection(d.profile.name, nxt.seeds, list(nxt.scenes), list(nxt.variants))
    try:
        with stopping.on_signals():
            jobs = default_jobs(d.study.name, d.profile.name) if args.jobs is None else args.jobs
            outcome = run_study(d.study.name, sel, jobs=jobs, lease_s=args.lease, wait=True)
    except KeyboardInterrupt as exc:
        stop = stopping.as_stopped(exc)
        with contextlib.suppress(OSError):  # after SIGHUP the terminal may be gone; the store has the record
            echo(f"stopped by {stop.name}: {plural(stop.finished, 'run')} finished, {stop.killed} recorded KILLED"
                 f" (stop_signal={stop.name}); resume with: {shlex.join(['study', *argv])}")
        return stop.exit_status, ""
    return outcome.exit_status, outcome.parent_run_id
