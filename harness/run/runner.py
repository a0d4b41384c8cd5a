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
   joblib for ``jobs > 1``, or submitit's local and SLURM executors) and ``_finish`` ends the
   parent run with the counts;
4. each job runs a ``run.task.RunTask``: it claims, trains and records its child run.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from ftgspp.bench import warmup
from ftgspp.errors import InputError
from harness.run import lease, progress
from harness.run.launchers import check_launcher, check_launcher_args, launch, split_launcher_args
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


@dataclass
class StudyOutcome:
    """What one ``study run`` did."""

    total: int
    skipped: int
    launched: int
    finished: int = 0
    failed: int = 0
    diverged: int = 0
    claimed_elsewhere: int = 0  # launched, but another invocation had claimed or finished it
    parent_run_id: str = ""
    results: list[dict[str, Any]] = field(default_factory=list)


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
    echo("compiling the CPU kernels (once per install or code change:"
         f" ~{fmt_duration(warmup.COLD_COMPILE_S)} on an idle 2-core machine, longer under load) ...")
    t0 = time.time()
    proc = subprocess.run(list(WARMUP), capture_output=True, text=True)
    if proc.returncode != 0:  # the runs will compile (or fail) themselves and say why
        echo(f"  kernel warm-up failed: {(proc.stderr.strip().splitlines() or ['no output'])[-1]}")
        return
    echo(f"  kernels compiled in {time.time() - t0:.0f} s")


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
) -> StudyOutcome:
    """Run the missing or failed runs of study ``name``; see the module docstring. ``study``:
    a spec built in code (``study budget``, cli.budget) instead of ``studies/<name>.yaml``."""
    inv = _validate(name, sel, jobs, launcher, lease_s, studies_dir, out_root, study)
    # the workers import and load their kernels while this process opens the store and makes scenes
    warm = prewarm(launcher, jobs, inv.launcher_args) if train_fn is None else None
    store, exp_id = _open_experiment(inv)
    todo, elsewhere, trainer = _find_pending(inv, store, rerun_stale, echo)
    outcome = StudyOutcome(total=len(inv.planned), skipped=len(inv.planned) - len(todo), launched=len(todo))
    _announce(inv, todo, elsewhere, echo)
    if not todo:
        if warm is not None:
            warm.wait()  # nothing to run: the warm-up ends before the process does (seconds)
        echo(f"browse: {ui_link(inv.uri, exp_id)}")
        return outcome
    local_kernels = train_fn is None and inv.launcher != "slurm"  # workers here train with the cpu kernels
    text, runs_s = progress.expected(inv.study.profile(inv.sel.profile), len(todo), jobs,
                                     local_kernels and not warmup.kernels_cached())
    echo(f"expected: {text}")
    _prepare(inv, todo, generate, local_kernels, warm, echo)  # scenes, kernels, warm workers
    parent_id, stamp = _open_parent(store, exp_id, inv, todo)
    outcome.parent_run_id = parent_id
    # absolute: submitit's folder lives under it and jobs on other nodes must find it
    sweep_dir = (inv.out_root / name / f"{stamp}-{parent_id[:8]}").resolve()
    echo(f"outputs: {os.path.relpath(sweep_dir)}/VARIANT/SCENE/SEED/, each run's log there: study_{name}.log")
    task = _task(inv, exp_id, parent_id, todo, sweep_dir, runs_s, train_fn, trainer)
    _launch_runs(inv, store, task, todo, sweep_dir, outcome)
    _finish(inv, store, exp_id, outcome, echo)
    return outcome


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
    todo, elsewhere = pending(existing, inv.planned, inv.lease_s, trainer)
    for line in foreign_domain_notes(existing, inv.planned):
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


def _open_parent(store: Store, exp_id: str, inv: Invocation, todo: list[PlannedRun]) -> tuple[str, str]:
    """The invocation's parent run (tags, params, the study file); returns (run id, stamp)."""
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
    parent_id = store.create_run(exp_id, f"{study.name}-{sel.profile}-{stamp}", tags)
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


def _task(inv: Invocation, exp_id: str, parent_id: str, todo: list[PlannedRun], sweep_dir: Path, runs_s: float,
          train_fn: TrainFn | None, trainer: str) -> RunTask:
    """What each job runs: claim, train and record its child run of ``parent_id``."""
    return RunTask(
        uri=inv.uri,
        experiment_id=exp_id,
        parent_run_id=parent_id,
        jobs=[JobInfo(p.spec.label, p.tags, p.config_hash, p.spec.scene.synth, p.params.get("threads", ""))
              for p in todo],
        progress_path=str(sweep_dir / "progress.jsonl"),
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
    the parent run FAILED (KILLED on an interrupt) and the error goes on, except under submitit
    (local, slurm): a job that died fails the whole array, but every run recorded itself."""
    parent_id = task.parent_run_id
    # progress bars of parallel workers would interleave (progress is not part of the hash)
    quiet = ["progress=false"] if inv.jobs > 1 or inv.launcher in ("local", "slurm") else []
    job_overrides = [[*p.spec.overrides, *quiet, f"hydra.sweep.subdir={p.spec.label}"] for p in todo]
    try:  # through the workers warmed above (run.prewarm), which the launcher reuses
        returns = launch(job_overrides, task, sweep_dir=sweep_dir, jobs=inv.jobs, job_name=f"study_{inv.name}",
                         launcher=inv.launcher, launcher_args=inv.launcher_args)
        _tally(outcome, todo, returns)
    except Exception as exc:  # e.g. submitit's UncompletedJobError: a job died without returning
        if inv.launcher not in ("local", "slurm"):
            store.terminate(parent_id, "FAILED", {"error": f"{type(exc).__name__}: {exc}"[:1000]})
            raise
        _tally_from_store(outcome, store, inv.experiment, inv.name, parent_id, exc)
    except BaseException as exc:
        status = "KILLED" if isinstance(exc, KeyboardInterrupt) else "FAILED"
        store.terminate(parent_id, status, {"error": f"{type(exc).__name__}: {exc}"[:1000]})
        raise


def _tally(outcome: StudyOutcome, todo: list[PlannedRun], returns: list[Any]) -> None:
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


def _tally_from_store(outcome: StudyOutcome, store: Store, experiment: str, study: str, parent_id: str,
                      error: BaseException) -> None:
    """Count the children of ``parent_id`` as stored: a job that died (killed, node lost,
    time limit) makes submitit raise for the whole array, but every run recorded itself."""
    for rec in load_runs(store, experiment, study):
        if rec.tags.get("mlflow.parentRunId") != parent_id:
            continue
        res = {"label": rec.tags.get("mlflow.runName", ""), "run_id": rec.run_id, "status": rec.status,
               "failure": rec.failure, "error": rec.error}
        outcome.results.append(res)
        outcome.finished += rec.status == "FINISHED"
        outcome.failed += rec.status in ("FAILED", "KILLED")
        outcome.diverged += rec.failure == "diverged"
    lost = outcome.launched - len(outcome.results)
    outcome.failed += max(0, lost)
    print(f"[study] launcher: {type(error).__name__}: {str(error).strip().splitlines()[0] if str(error).strip() else ''}"
          f" ({max(0, lost)} jobs left no finished record; their claims expire and the next `study run` retries them)",
          flush=True)


def _finish(inv: Invocation, store: Store, exp_id: str, outcome: StudyOutcome, echo: Callable[[str], None]) -> None:
    """End the parent run FINISHED with the counts; say what happened and where to browse it."""
    store.terminate(outcome.parent_run_id, "FINISHED", {"n_finished": str(outcome.finished),
                                                        "n_failed": str(outcome.failed),
                                                        "n_diverged": str(outcome.diverged),
                                                        "n_claimed_elsewhere": str(outcome.claimed_elsewhere)})
    elsewhere_txt = f", {outcome.claimed_elsewhere} claimed by other invocations" if outcome.claimed_elsewhere else ""
    echo(f"{inv.name}: {outcome.finished} finished, {outcome.failed} failed ({outcome.diverged} diverged),"
         f" {outcome.skipped} skipped{elsewhere_txt}; parent run {outcome.parent_run_id} in {inv.experiment}"
         f" at {inv.uri}")
    echo(f"browse: {ui_link(inv.uri, exp_id)}")
