"""Run a study: expand, skip what already finished, launch the rest, record every outcome.

``run_study`` is what ``study run`` calls; it reads as its steps:

1. ``_validate``: expand the study file into runs (variant x scene x seed) and compose every
   run's config (``spec.plan``); bad overrides, launcher arguments or an unusable store stop
   here, before the store is touched;
2. ``_open_experiment``, ``_find_pending``: read the study's runs and skip every (study,
   variant, scene, seed, config_hash) already FINISHED or claimed by a live worker of
   another invocation (``run.lease``);
3. ``_prepare``: generate missing synthetic scenes, compile the cpu kernels and wait for the
   warm workers (``run.prewarm``), all before ``_open_parent`` opens one MLflow parent run;
   ``_launch_runs`` launches the rest through a Hydra launcher (``run.launchers``: basic,
   joblib for ``jobs > 1``, or submitit's local and SLURM executors);
4. each job runs a ``run.task.RunTask``: it claims, trains and records its child run;
5. with ``wait`` (``study run`` without ``--no-wait``): wait for the runs other live invocations
   hold, and run those they leave without a result; ``_finish`` settles the plan against the
   store (``run.completion``: the exit status) and ends the parent run with the counts.

Ctrl-C, SIGTERM and SIGHUP stop it at any step (``run.stopping``): no further job starts, the
workers record their runs KILLED with the signal, what they leave RUNNING is ended KILLED here,
the parent run ends KILLED, and ``Stopped`` goes on to the caller (``study run`` prints the
command that resumes).
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

from ftgspp.bench import warmup
from ftgspp.errors import InputError
from harness.run import completion, lease, progress, stopping
from harness.run.completion import StudyOutcome
from harness.run.launchers import (check_launcher, check_launcher_args, effective_launcher, launch, split_launcher_args,
                                   stop_launching)
from harness.run.prewarm import Prewarm, prewarm
from harness.run.scenes import Generator, ensure_scene, scene_lock
from harness.run.task import JobInfo, RunTask, TrainFn
from harness.spec.plan import PlannedRun, plan_runs
from harness.spec.runs import Selection, command_line, describe_runs, expand
from harness.spec.study_files import load_study
from harness.spec.study_schema import StudySpec, fmt_duration
from harness.tracking.conventions import experiment_tags, scene_dataset, source_tags, ui_link
from harness.tracking.provenance import git_sha, trainer_fingerprint
from harness.tracking.records import RunRecord, load_runs, tracking_target
from harness.tracking.store import Store, check_store

OUT_ROOT = Path("outputs/studies")


@dataclass(frozen=True)
class Invocation:
    """One validated ``study run``: its planned runs, where they are recorded, how they run."""

    name: str
    study: StudySpec
    sel: Selection  # without the launcher's overrides (``hydra.launcher.*``: ``launcher_args``)
    planned: list[PlannedRun]
    command: str
    uri: str
    experiment: str
    jobs: int
    launcher: str
    launcher_args: list[str]
    lease_s: float
    out_root: Path


WARMUP = (sys.executable, "-m", "ftgspp.bench.warmup")


def warm_kernels(echo: Callable[[str], None]) -> None:
    """Compile the cpu kernels once, with a line saying so, when Numba's cache is cold: else
    every worker would compile them at once, silently, for minutes."""
    if warmup.kernels_cached():
        return
    load, cores = os.getloadavg()[0], os.cpu_count() or 1
    busy = max(1.0, (load + 1) / cores)  # the compile is one more process on a machine with `load` already
    at_load = (f", about {fmt_duration(warmup.COLD_COMPILE_S * busy)} at this load (load average {load:.1f} on"
               f" {cores} cores)") if busy > 1.1 else ""
    echo("compiling the CPU kernels (once per install or code change:"
         f" ~{fmt_duration(warmup.COLD_COMPILE_S)} on an idle 2-core machine{at_load}) ...")
    t0 = time.time()
    proc = subprocess.run(list(WARMUP), capture_output=True, text=True)
    if proc.returncode != 0:  # the runs will compile (or fail) themselves and say why
        echo(f"  kernel warm-up failed: {(proc.stderr.strip().splitlines() or ['no output'])[-1]}")
        return
    echo(f"  kernels compiled in {time.time() - t0:.0f} s")


def run_study(
    name: str,
    sel: Selection,
    *,
    jobs: int = 1,
    launcher: str = "basic",
    lease_s: float | None = None,
    studies_dir: Path | None = None,
    out_root: Path = OUT_ROOT,
    train_fn: TrainFn | None = None,
    generate: Generator | None = None,
    echo: Callable[[str], None] = print,
    rerun_stale: bool = False,
    study: StudySpec | None = None,
    wait: bool = False,
) -> StudyOutcome:
    """Run the missing or failed runs of study ``name``; see the module docstring. ``study``:
    a spec built in code (``study budget``, cli.budget) instead of ``studies/<name>.yaml``.
    ``wait``: wait for the runs other live invocations hold and run those they leave without a
    result; else they are left to them (``outcome.exit_status`` 3). Ctrl-C, SIGTERM and SIGHUP
    raise ``run.stopping.Stopped`` once every run in progress is recorded KILLED."""
    stopping.reset()
    with stopping.on_signals():
        inv = _validate(name, sel, jobs, launcher, lease_s, studies_dir, out_root, study)
        # the workers import and load their kernels while this process opens the store and makes scenes
        warm = prewarm(launcher, jobs, inv.launcher_args) if train_fn is None else None
        store, exp_id = _open_experiment(inv)
        todo, elsewhere, trainer = _find_pending(inv, store, rerun_stale, echo)
        outcome = StudyOutcome(total=len(inv.planned), skipped=len(inv.planned) - len(todo), launched=len(todo))
        _announce(inv, todo, elsewhere, echo)
        launches = _Launches(inv, store, exp_id, outcome, train_fn, trainer, generate, warm, echo)
        try:
            if todo:
                launches(todo)
            elif warm is not None:
                warm.wait()  # nothing to run: the warm-up ends before the process does (seconds)
            while wait and (held := completion.settle(load_runs(store, inv.experiment, name), inv.planned,
                                                      inv.lease_s, trainer).held):
                completion.wait_for_holders(store, inv.experiment, name, held, inv.lease_s, echo)
                again, _, _ = _find_pending(inv, store, rerun_stale, lambda line: None)
                if again := [p for p in again if p.key in {r.key for r in held}]:  # their holders left no result
                    echo(f"{len(again)} of them ended without a result: running {len(again)} here")
                    outcome.launched += len(again)
                    launches(again)
            _finish(inv, store, exp_id, outcome, trainer, echo)
        except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM, SIGHUP: record what was running, then stop
            stop = stopping.as_stopped(exc)
            stopping.reap(stopping.grace_seconds() + 5)  # what is left of the workers
            if outcome.parent_run_id:
                for line in completion.end_stopped(store, inv.experiment, name, outcome.parent_run_id, stop):
                    echo(line)
            raise stop from None
        return outcome


@dataclass
class _Launches:
    """The launches of one invocation, under its one parent run (opened by the first)."""

    inv: Invocation
    store: Store
    exp_id: str
    outcome: StudyOutcome
    train_fn: TrainFn | None
    trainer: str
    generate: Generator | None
    warm: Prewarm | None
    echo: Callable[[str], None]
    sweep_dir: Path | None = None
    rounds: int = 0

    def __call__(self, todo: list[PlannedRun]) -> None:
        inv, echo = self.inv, self.echo
        local_kernels = self.train_fn is None and inv.launcher != "slurm"  # workers here train with the cpu kernels
        text, runs_s = progress.expected(inv.study.profile(inv.sel.profile), len(todo), inv.jobs,
                                         local_kernels and not warmup.kernels_cached())
        echo(f"expected: {text}")
        _prepare(inv, todo, self.generate, local_kernels, self.warm, echo)  # scenes, kernels, warm workers
        if self.sweep_dir is None:
            parent_id, stamp = _open_parent(self.store, self.exp_id, inv, todo, self.outcome)
            # absolute: submitit's folder lives under it and jobs on other nodes must find it
            self.sweep_dir = (inv.out_root / inv.name / f"{stamp}-{parent_id[:8]}").resolve()
            echo(f"outputs: {os.path.relpath(self.sweep_dir)}/VARIANT/SCENE/SEED/, each run's log there:"
                 f" study_{inv.name}.log")
        self.rounds += 1
        progress_file = "progress.jsonl" if self.rounds == 1 else f"progress-{self.rounds}.jsonl"
        task = _task(inv, self.exp_id, self.outcome.parent_run_id, todo, self.sweep_dir / progress_file, runs_s,
                     self.train_fn, self.trainer)
        _launch_runs(inv, self.store, task, todo, self.sweep_dir, self.outcome)


def _validate(name: str, sel: Selection, jobs: int, launcher: str, lease_s: float | None, studies_dir: Path | None,
              out_root: Path, study: StudySpec | None) -> Invocation:
    """Plan every run and check the launcher and the store: bad input stops here, before the
    store is touched."""
    if jobs < 1:
        raise InputError("--jobs", "must be at least 1")
    try:
        lease_s = lease.lease_seconds(lease_s)
    except ValueError as exc:
        raise InputError("--lease", str(exc)) from None
    study = study or load_study(name, studies_dir)
    command = command_line(name, sel, jobs, launcher)
    run_overrides, launcher_args = split_launcher_args(sel.overrides)
    sel = dataclasses.replace(sel, overrides=run_overrides)
    planned = plan_runs(expand(study, sel))  # every bad input stops here ...
    uri, experiment = tracking_target(sel.overrides, planned[0].params, name)
    check_launcher(launcher, uri)
    check_launcher_args(launcher, launcher_args, Path(out_root).resolve())
    check_store(uri)  # ... or here, before anything is written
    return Invocation(name, study, sel, planned, command, uri, experiment, jobs, launcher, launcher_args, lease_s,
                      Path(out_root))


def _open_experiment(inv: Invocation) -> tuple[Store, str]:
    """The store and the study's experiment id; the experiment is created once, here, before
    any worker starts, and its description is set."""
    store = Store(inv.uri)
    exp_id = store.experiment_id(inv.experiment)
    assert exp_id is not None
    store.set_experiment_tags(exp_id, experiment_tags(inv.study.question,
                                                      f"study run {inv.name} --profile {inv.sel.profile}",
                                                      f"study report {inv.name}"))
    return store, exp_id


def _find_pending(inv: Invocation, store: Store, rerun_stale: bool,
                  echo: Callable[[str], None]) -> tuple[list[PlannedRun], list[RunRecord], str]:
    """(runs to launch, live claims of other invocations, the trainer fingerprint a finished run
    must carry to count as done: "" for any), from the study's runs in the store; says which
    finished runs come from another determinism domain."""
    existing = load_runs(store, inv.experiment, inv.name)
    trainer = trainer_fingerprint() if rerun_stale else ""  # --rerun-stale: runs of older code are not done
    todo, elsewhere = completion.pending(existing, inv.planned, inv.lease_s, trainer)
    for line in completion.foreign_domain_notes(existing, inv.planned):
        echo(line)
    return todo, elsewhere, trainer


def _announce(inv: Invocation, todo: list[PlannedRun], elsewhere: list[RunRecord], echo: Callable[[str], None]) -> None:
    """What is planned, already finished, running elsewhere (one line each) and left to run."""
    n_done = len(inv.planned) - len(todo) - len(elsewhere)
    echo(f"{inv.name} ({inv.sel.profile}): {describe_runs([p.spec for p in inv.planned])};"
         f" {n_done} already finished, " + (f"{len(elsewhere)} running elsewhere, " if elsewhere else "")
         + f"{len(todo)} to run"
         + (f" with {inv.jobs} parallel jobs" if inv.jobs > 1 and todo else "")
         + (f" through the {inv.launcher} launcher" if inv.launcher != "basic" and todo else ""))
    for rec in elsewhere:
        echo(f"  running elsewhere: {rec.tags.get('mlflow.runName', rec.key)} ({lease.describe(rec)})")


def _prepare(inv: Invocation, todo: list[PlannedRun], generate: Generator | None, local_kernels: bool,
             warm: Prewarm | None, echo: Callable[[str], None]) -> None:
    """Make the missing synthetic scenes, compile the cpu kernels once and wait for the warm
    workers: all before the parent run exists, so an interrupt here leaves nothing RUNNING."""
    for scene in {p.spec.scene.name: p.spec.scene for p in todo}.values():
        with scene_lock(scene):  # another invocation may be generating it right now
            ensure_scene(scene, generate, echo)
    if local_kernels:
        warm_kernels(echo)
    if warm is not None:
        warm.wait()
        if warm.error is not None:
            echo(f"  worker warm-up failed ({type(warm.error).__name__}: {warm.error}); the launcher starts its own")


def _open_parent(store: Store, exp_id: str, inv: Invocation, todo: list[PlannedRun],
                 outcome: StudyOutcome) -> tuple[str, str]:
    """The invocation's parent run (tags, params, the study file), its id in ``outcome`` as soon
    as it exists (a stop ends it KILLED from then on); returns (run id, stamp)."""
    study, sel, planned = inv.study, inv.sel, inv.planned
    stamp = time.strftime("%Y%m%d-%H%M%S")
    tags = {
        "study": study.name,
        "profile": sel.profile,
        "kind": "study",
        "invocation": json.dumps({**asdict(sel), "jobs": inv.jobs, "launcher": inv.launcher,
                                  "launcher_overrides": inv.launcher_args}),
        "command": inv.command,
        **source_tags(inv.command),
        "git_sha": git_sha(),
        "trainer_fingerprint": trainer_fingerprint(),
        "n_runs": str(len(planned)),
        "n_launched": str(len(todo)),
    }
    parent_id = outcome.parent_run_id = store.create_run(exp_id, f"{study.name}-{sel.profile}-{stamp}", tags)
    n_seeds = len({p.spec.seed for p in planned})
    store.log_batch(parent_id, params={"profile": sel.profile, "jobs": inv.jobs, "launcher": inv.launcher,
                                       "seeds": n_seeds, "base_seed": study.base_seed})
    # the study's scenes as dataset inputs: the runs table shows them on the parent's row
    scenes = {p.spec.scene.name: p for p in todo}.values()
    store.log_inputs(parent_id, [scene_dataset(p.spec.scene.name, p.params["data.path"], p.params["data.format"],
                                               p.spec.scene.synth) for p in scenes])
    if study.path is not None:  # the study definition this invocation used
        store.log_artifact(parent_id, study.path)
    return parent_id, stamp


def _task(inv: Invocation, exp_id: str, parent_id: str, todo: list[PlannedRun], progress_path: Path, runs_s: float,
          train_fn: TrainFn | None, trainer: str) -> RunTask:
    """What each job runs: claim, train and record its child run of ``parent_id``."""
    return RunTask(
        uri=inv.uri,
        experiment_id=exp_id,
        parent_run_id=parent_id,
        jobs=[JobInfo(p.spec.label, p.tags, p.config_hash, p.spec.scene.synth, p.params.get("threads", ""))
              for p in todo],
        progress_path=str(progress_path),
        started_at=time.time(),
        expected_total_s=runs_s,
        train_fn=train_fn,
        lease_s=inv.lease_s,
        command=inv.command,
        trainer=trainer,
    )


def _launch_runs(inv: Invocation, store: Store, task: RunTask, todo: list[PlannedRun], sweep_dir: Path,
                 outcome: StudyOutcome) -> None:
    """Launch ``todo`` and count what came back into ``outcome``. A launcher that raises ends
    the parent run FAILED and the error goes on, except under submitit (local, slurm): a job that
    died fails the whole array, but every run recorded itself. A stop (``KeyboardInterrupt``) goes
    on to ``run_study``; while it is being handled no further job starts and the workers of this
    host get the time to record their runs (``_drain``)."""
    parent_id = task.parent_run_id
    # progress bars of parallel workers would interleave (progress is not part of the hash)
    quiet = ["progress=false"] if inv.jobs > 1 or inv.launcher in ("local", "slurm") else []
    job_overrides = [[*p.spec.overrides, *quiet, f"hydra.sweep.subdir={p.spec.label}"] for p in todo]
    try:  # through the workers warmed above (run.prewarm), which the launcher reuses
        with stopping.while_stopping(lambda: _drain(inv, store, parent_id)):
            returns = launch(job_overrides, task, sweep_dir=sweep_dir, jobs=inv.jobs, job_name=f"study_{inv.name}",
                             launcher=inv.launcher, launcher_args=inv.launcher_args)
        completion.tally(outcome, todo, returns)
    except Exception as exc:  # e.g. submitit's UncompletedJobError: a job died without returning
        if inv.launcher not in ("local", "slurm"):
            store.terminate(parent_id, "FAILED", {"error": f"{type(exc).__name__}: {exc}"[:1000]})
            raise
        completion.tally_from_store(outcome, store, inv.experiment, inv.name, parent_id, exc)
    except SystemExit as exc:
        store.terminate(parent_id, "FAILED", {"error": f"{type(exc).__name__}: {exc}"[:1000]})
        raise


def _drain(inv: Invocation, store: Store, parent_id: str) -> None:
    """In the stop signal's handler, before the launcher sees the stop (joblib would kill its
    workers at once): start no further job, and give the workers of this host, told to stop
    (``stopping.forward``), the grace period to record their runs KILLED."""
    stop_launching()
    if effective_launcher(inv.launcher, inv.jobs) != "basic":  # basic: the run is in this process
        completion.workers_recorded(store, inv.experiment, inv.name, parent_id, stopping.grace_seconds() + 5)


def _finish(inv: Invocation, store: Store, exp_id: str, outcome: StudyOutcome, trainer: str,
            echo: Callable[[str], None]) -> None:
    """Settle the plan against the store (``completion``: the exit status), end the parent run
    FINISHED with the counts, say what happened, what is left and where to browse it."""
    comp = completion.settle(load_runs(store, inv.experiment, inv.name), inv.planned, inv.lease_s, trainer)
    outcome.exit_status = comp.exit_status
    if outcome.parent_run_id:
        store.terminate(outcome.parent_run_id, "FINISHED", {
            "n_finished": str(outcome.finished), "n_failed": str(outcome.failed), "n_diverged": str(outcome.diverged),
            "n_claimed_elsewhere": str(outcome.claimed_elsewhere), "n_held_elsewhere": str(len(comp.held)),
            "n_missing": str(len(comp.missing))})
        elsewhere_txt = f", {outcome.claimed_elsewhere} claimed by other invocations" * bool(outcome.claimed_elsewhere)
        echo(f"{inv.name}: {outcome.finished} finished, {outcome.failed} failed ({outcome.diverged} diverged),"
             f" {outcome.skipped} skipped{elsewhere_txt}; parent run {outcome.parent_run_id} in {inv.experiment}"
             f" at {inv.uri}")
    for line in completion.summary(comp, inv.lease_s, inv.command):
        echo(line)
    echo(f"browse: {ui_link(inv.uri, exp_id)}")
