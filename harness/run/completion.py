"""How a ``study run`` ends: which planned runs are done, held elsewhere or missing, its exit
status, waiting for other invocations, and what a stopped invocation records.

A planned run is *done* when its (variant, scene, seed, config_hash) has a FINISHED run, or when
its latest attempt FAILED with a reason of its own (``diverged``, ``input_error``, ``crashed``,
``harness``): a failed run is an answer the report counts. It is *held* while another
invocation's claim on it is live (``run.lease``), and *missing* otherwise (killed, taken over
and not finished, a job that died without a record): the next ``study run`` runs it.

``study run`` exits with ``Completion.exit_status``: 0 when every planned run is done, 3 when some
are held (with ``--no-wait``; else it waits for them first), 4 when some are missing; 2 is bad
input and 128 + N a stop by signal N (``EXIT_STATUSES``: the text ``study run --help`` shows).
"""

from __future__ import annotations

import socket
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable

from harness.run import lease, stopping
from harness.tracking.records import RunRecord, load_runs
from harness.tracking.store import Store

if TYPE_CHECKING:
    from harness.spec.plan import PlannedRun

EXIT_DONE = 0  # every planned run done
EXIT_INPUT = 2  # bad input: one line, nothing written
EXIT_HELD = 3  # runs held by another live invocation (--no-wait), each named with its holder and expiry
EXIT_INCOMPLETE = 4  # runs with no final record (killed elsewhere, lost, a job that died): run again
# 128 + N: stopped by signal N (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP), after the line that resumes
EXIT_STATUSES = f"""exit status:
  {EXIT_DONE}      every planned run FINISHED (or FAILED with a reason: diverged, crashed, input_error)
  {EXIT_INPUT}      bad input: one line, nothing written
  {EXIT_HELD}      runs held by another live invocation (--no-wait): a line per run names the holder's
         host, pid and lease expiry
  {EXIT_INCOMPLETE}      runs left without a final record (killed elsewhere, lost, a job that died):
         run the same command again
  128+N  stopped by signal N (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP): the runs in progress are
         recorded KILLED with the signal; the last line is the command that resumes"""

FAILED_FOR_GOOD = ("diverged", "input_error", "crashed", "harness")  # failures that are an answer


@dataclass
class StudyOutcome:
    """What one ``study run`` did; ``exit_status`` is settled at its end (``Completion``)."""

    total: int
    skipped: int
    launched: int
    finished: int = 0
    failed: int = 0
    diverged: int = 0
    claimed_elsewhere: int = 0  # launched, but another invocation had claimed or finished it
    parent_run_id: str = ""
    results: list[dict[str, Any]] = field(default_factory=list)
    exit_status: int = EXIT_DONE


@dataclass
class Completion:
    """The planned runs by state (labels), from the tracking store at the end."""

    done: list[str] = field(default_factory=list)
    held: list[RunRecord] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)

    @property
    def exit_status(self) -> int:
        return EXIT_HELD if self.held else EXIT_INCOMPLETE if self.missing else EXIT_DONE


def pending(existing: list[RunRecord], planned: list[PlannedRun], lease_s: float = lease.DEFAULT_LEASE_S,
            trainer: str = "") -> tuple[list[PlannedRun], list[RunRecord]]:
    """(planned runs to launch, live claims of other invocations that are left to them),
    given the study's ``existing`` child runs.

    A run is launched unless it FINISHED or a live worker holds it; stale RUNNING runs are
    taken over by the job that claims the run (``run.lease.acquire``), not here. A finished run
    scored without LPIPS is run again once the weights are there.
    """
    done = {r.key for r in existing if lease.counts_as_done(r, trainer)}
    live = {r.key: r for r in existing if lease.is_live(r, lease_s) and r.key not in done}
    todo = [p for p in planned if p.key not in done and p.key not in live]
    keys = {p.key for p in planned}
    return todo, [r for k, r in live.items() if k in keys]


def foreign_domain_notes(existing: list[RunRecord], planned: list[PlannedRun]) -> list[str]:
    """One line per finished run in ``existing`` that counts as done here although its bits come
    from another determinism domain than this machine would give it (or from no recorded one)."""
    from ftgspp.runtime.determinism import expected_domain_id

    by_key = {p.key: p for p in planned}
    expected: dict[tuple[str, int, str], str | None] = {}
    notes = []
    for rec in existing:
        p = by_key.get(rec.key)
        if rec.status != "FINISHED" or p is None:
            continue
        # like with like: the thread count the run recorded (a joblib worker may get fewer
        # threads than planned) and the run's own kernel dispatch
        threads = rec.tags.get("determinism.torch_threads") or p.params.get("threads", "0")
        settings = (p.params.get("determinism", "default"), int(threads), p.params.get("dispatch", "native"))
        if settings not in expected:
            expected[settings] = expected_domain_id(*settings)
        here, got = expected[settings], rec.tags.get("determinism.id", "")
        if here is not None and got != here:
            notes.append(f"[resume] {p.spec.label}: finished in determinism domain {got or 'unrecorded'}, this machine"
                         f" gives {here}; counted as done (its numbers need not match a run here bit for bit)")
    return notes


def settle(existing: list[RunRecord], planned: list[PlannedRun], lease_s: float, trainer: str = "") -> Completion:
    """Sort ``planned`` into done, held and missing, given the study's ``existing`` child runs."""
    by_key: dict = {}
    for rec in sorted(existing, key=lambda r: r.start_time):
        by_key.setdefault(rec.key, []).append(rec)
    out = Completion()
    for p in planned:
        attempts = by_key.get(p.key, [])
        live = [r for r in attempts if lease.is_live(r, lease_s)]
        ended = [r for r in attempts if r.status != "RUNNING"]
        if any(lease.counts_as_done(r, trainer) for r in attempts):
            out.done.append(p.spec.label)
        elif live:
            out.held.append(live[-1])
        elif ended and ended[-1].status == "FAILED" and ended[-1].failure in FAILED_FOR_GOOD:
            out.done.append(p.spec.label)
        else:
            out.missing.append(p.spec.label)
    return out


def wait_for_holders(store: Store, experiment: str, study: str, held: list[RunRecord], lease_s: float,
                     echo: Callable[[str], None]) -> None:
    """Wait until none of the ``held`` runs is live any more: its holder ended it, its lease
    expired or its holder process is gone. Says what it waits for and when the leases expire."""
    echo(f"waiting for {len(held)} run{'s' * (len(held) != 1)} held by other invocations"
         " (study run --no-wait: exit 3 instead):")
    for rec in held:
        echo(f"  {lease.held_line(rec, lease_s)}")
    ids = {r.run_id for r in held}
    poll_s = max(0.2, min(5.0, lease_s / 10))
    while True:
        now = {r.run_id: r for r in load_runs(store, experiment, study) if r.run_id in ids}
        if not any(lease.is_live(r, lease_s) for r in now.values()):
            return
        time.sleep(poll_s)


def settle_children(store: Store, experiment: str, study: str, parent_id: str) -> list[RunRecord]:
    """The child runs of ``parent_id`` as stored."""
    return [r for r in load_runs(store, experiment, study) if r.tags.get("mlflow.parentRunId") == parent_id]


def workers_recorded(store: Store, experiment: str, study: str, parent_id: str, grace_s: float) -> None:
    """Wait (up to ``grace_s``) until no child run of ``parent_id`` is RUNNING under a live worker
    of this host other than this process: the workers told to stop have recorded their runs."""
    me = lease.owner_id()
    deadline = time.monotonic() + grace_s
    while time.monotonic() < deadline:
        busy = [r for r in settle_children(store, experiment, study, parent_id)
                if r.status == "RUNNING" and r.tags.get(lease.OWNER) != me and not lease.holder_gone(r)
                and lease.holder(r)[0] == socket.gethostname()]
        if not busy:
            return
        time.sleep(0.2)


def end_stopped(store: Store, experiment: str, study: str, parent_id: str, stop: stopping.Stopped) -> list[str]:
    """Record a stopped invocation: every child run of ``parent_id`` left RUNNING by this process
    or by a worker of this host that is gone is ended KILLED; every KILLED child carries the
    invocation's signal (``stop_signal``); the parent ends KILLED with the counts. Runs of
    workers elsewhere (SLURM nodes) are left to them. Fills ``stop.finished`` and ``stop.killed``;
    returns notes for runs left RUNNING elsewhere."""
    me = lease.owner_id()
    tags = {"failure": "interrupted", "stop_signal": stop.name, "error": f"stopped by {stop.name}"}
    notes = []
    for rec in settle_children(store, experiment, study, parent_id):
        if rec.status == "RUNNING" and (rec.tags.get(lease.OWNER) == me or lease.holder_gone(rec)):
            store.terminate(rec.run_id, "KILLED", tags)
        elif rec.status == "RUNNING":
            notes.append(f"  still running elsewhere: {rec.tags.get('mlflow.runName', rec.run_id)}"
                         f" ({lease.describe(rec)}); it records itself")
        elif rec.status == "KILLED" and rec.tags.get("stop_signal") != stop.name:
            store.log_batch(rec.run_id, tags=tags)
    children = settle_children(store, experiment, study, parent_id)
    stop.finished = sum(r.status == "FINISHED" for r in children)
    stop.killed = sum(r.status == "KILLED" for r in children)
    store.terminate(parent_id, "KILLED", {**tags, "n_finished": str(stop.finished), "n_killed": str(stop.killed),
                                          "n_failed": str(sum(r.status == "FAILED" for r in children))})
    return notes


def summary(comp: Completion, lease_s: float, command: str) -> list[str]:
    """What is left undone, one line per held run (holder and lease expiry), and why the exit
    status is not 0; nothing when every planned run is done."""
    lines = []
    if comp.held:
        lines.append(f"{len(comp.held)} planned run{'s are' if len(comp.held) != 1 else ' is'} held by other live"
                     f" invocations (exit status {EXIT_HELD}; without --no-wait `study run` waits for them):")
        lines += [f"  {lease.held_line(rec, lease_s)}" for rec in comp.held]
    if comp.missing:
        lines.append(f"{len(comp.missing)} planned run{'s have' if len(comp.missing) != 1 else ' has'} no final"
                     f" record ({', '.join(comp.missing[:5])}{', ...' if len(comp.missing) > 5 else ''}; exit status"
                     f" {EXIT_INCOMPLETE}): run `{command}` again")
    return lines


def tally(outcome: StudyOutcome, todo: list[PlannedRun], returns: list[Any]) -> None:
    """Count the launcher's job returns for ``todo`` into ``outcome``."""
    for run, ret in zip(todo, returns):
        try:
            res = ret.return_value
        except Exception as exc:  # the task itself failed (e.g. a tracking store error)
            res = {"label": run.spec.label, "status": "FAILED", "failure": "harness", "error": str(exc)}
        outcome.results.append(res)
        if res["status"] == "FINISHED":
            outcome.finished += 1
        elif res["status"] == "SKIPPED":
            outcome.claimed_elsewhere += 1
        else:
            outcome.failed += 1
            outcome.diverged += res.get("failure") == "diverged"


def tally_from_store(outcome: StudyOutcome, store: Store, experiment: str, study: str, parent_id: str,
                     error: BaseException) -> None:
    """Count the children of ``parent_id`` as stored: a job that died (killed, node lost,
    time limit) makes submitit raise for the whole array, but every run recorded itself."""
    counted = {r.get("run_id") for r in outcome.results}
    for rec in settle_children(store, experiment, study, parent_id):
        if rec.run_id in counted:
            continue
        res = {"label": rec.tags.get("mlflow.runName", ""), "run_id": rec.run_id, "status": rec.status,
               "failure": rec.failure, "error": rec.error}
        outcome.results.append(res)
        outcome.finished += rec.status == "FINISHED"
        outcome.failed += rec.status in ("FAILED", "KILLED")
        outcome.diverged += rec.failure == "diverged"
    lost = max(0, outcome.launched - len(outcome.results))
    outcome.failed += lost
    first = str(error).strip().splitlines()[0] if str(error).strip() else ""
    print(f"[study] launcher: {type(error).__name__}: {first} ({lost} jobs left no finished record; the next"
          " `study run` retries them, at once where their process is gone)", flush=True)
