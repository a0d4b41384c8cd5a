"""Run a study: expand, skip what already finished, launch the rest, record every outcome.

``run_study`` is what ``study run`` calls:

1. expand the study file into runs (variant x scene x seed) and compose every run's
   config (``harness.plan``) - bad overrides stop here, before the store is touched;
2. check the tracking store, skip every (study, variant, scene, seed, config_hash) already
   FINISHED or claimed by a live worker of another invocation (``harness.lease``);
3. generate missing synthetic scenes, open one MLflow parent run, and launch the rest
   through a Hydra launcher (``harness.launchers``: basic, joblib for ``jobs > 1``, or
   submitit's local and SLURM executors);
4. each job (``RunTask``, also in worker processes or on other nodes) claims its child run
   (a lease kept fresh by a heartbeat; a stale claim of a killed worker is taken over and
   marked FAILED, ``failure=interrupted``), trains through ``harness.train_app.run_training``
   with an ``MlflowTracker``, and ends the run FINISHED, or FAILED with ``failure`` =
   diverged | input_error | crashed and the error in ``error``. A run claimed elsewhere in
   the meantime comes back ``SKIPPED``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import json
import shlex
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

from omegaconf import DictConfig, OmegaConf

from ftgspp.errors import InputError
from ftgspp.tracking import RunResult
from harness import lease, progress
from harness.confighash import config_hash, flatten_config
from harness.conventions import scene_dataset, source_tags, system_metrics
from harness.launch import launch
from harness.launchers import check_launcher, check_launcher_args, split_launcher_args
from harness.plan import PlannedRun, plan_runs, resolve
from harness.provenance import git_sha, resolve_backend, resolve_device
from harness.records import RunRecord, experiment_name, load_runs
from harness.scenes import Generator, ensure_scene
from harness.studies import SceneSpec, Selection, StudySpec, describe_runs, expand, load_study
from harness.tracking import MlflowTracker, Store, check_store, resolve_uri

OUT_ROOT = Path("outputs/studies")
TrainFn = Callable[..., RunResult]  # (cfg: TrainConfig, out_dir: Path, tracker) -> RunResult


@dataclass(frozen=True)
class JobInfo:
    """What a worker needs to know about its run besides the composed config."""

    label: str
    tags: dict[str, str]
    config_hash: str
    synth: dict[str, Any] | None = None  # synthetic scene args (part of the hash)
    threads: str = ""  # torch threads the plan assumed (a joblib worker may get fewer)


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


def command_line(study: str, sel: Selection, jobs: int = 1, launcher: str = "basic") -> str:
    """The ``study run`` command that reproduces an invocation."""
    parts = ["study", "run", study, "--profile", sel.profile]
    if launcher != "basic":
        parts += ["--launcher", launcher]
    if sel.seeds is not None:
        parts += ["--seeds", str(sel.seeds)]
    if sel.scenes:
        parts += ["--scenes", ",".join(sel.scenes)]
    if sel.variants:
        parts += ["--variants", ",".join(sel.variants)]
    if jobs > 1:
        parts += ["--jobs", str(jobs)]
    return " ".join(shlex.quote(p) for p in [*parts, *sel.overrides])


def explicit_uri(overrides: list[str]) -> str | None:
    """The value of a ``tracking.uri=`` override, if the user gave one."""
    for o in overrides:
        if o.startswith("tracking.uri="):
            return o.split("=", 1)[1]
    return None


def tracking_target(sel: Selection, planned: list[PlannedRun]) -> tuple[str, str]:
    """(tracking URI, MLflow experiment name) of an invocation."""
    params = planned[0].params
    uri = resolve_uri(explicit_uri(sel.overrides), params["tracking.uri"])
    return uri, experiment_name(params["tracking.experiment"], planned[0].spec.study)


# --- inside each job (possibly a joblib worker process) ---------------------------------

_STORES: dict[str, Store] = {}


def _store(uri: str) -> Store:
    if uri not in _STORES:
        _STORES[uri] = Store(uri)
    return _STORES[uri]


def _default_train(cfg: Any, out_dir: Path, tracker: Any) -> RunResult:
    from harness import train_app  # looked up at call time so tests can monkeypatch it

    return train_app.run_training(cfg, out_dir, tracker)


def _outcome_tags(result: RunResult | None, exc: BaseException | None) -> tuple[str, dict[str, str]]:
    """MLflow status and the failure/error tags of a finished attempt."""
    if exc is not None:
        failure = "input_error" if isinstance(exc, InputError) else "crashed"
        message = str(exc) if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
        return "FAILED", {"failure": failure, "error": message}
    assert result is not None
    if result.status == "FINISHED":
        return "FINISHED", {}
    failure = result.failure or "failed"
    message = "loss became NaN/Inf" if failure == "diverged" else failure
    return "FAILED", {"failure": failure, "error": message}


def _artifact_subdir(path: Path, out_dir: Path) -> str | None:
    try:
        rel = path.resolve().relative_to(out_dir.resolve()).parent.as_posix()
    except ValueError:
        return None
    return None if rel == "." else rel


@dataclass
class RunTask:
    """Hydra task function: one child run. Picklable (plain data, no logger, lock or client
    inside), so joblib workers and submitit jobs on other nodes can run it."""

    uri: str
    experiment_id: str
    parent_run_id: str
    jobs: list[JobInfo]
    progress_path: str
    started_at: float
    train_fn: TrainFn | None = None
    lease_s: float = lease.DEFAULT_LEASE_S
    command: str = ""

    def __call__(self, dcfg: DictConfig) -> dict[str, Any]:
        from hydra.core.hydra_config import HydraConfig

        hydra_cfg = HydraConfig.get()
        job = self.jobs[int(hydra_cfg.job.num)]
        out_dir = Path(hydra_cfg.runtime.output_dir)
        cfg = resolve(dcfg, job.label)
        store = _store(self.uri)
        claim = lease.acquire(store, self.experiment_id, job.label,
                              {**job.tags, "kind": "run", "mlflow.parentRunId": self.parent_run_id}, self.lease_s)
        if claim.run_id is None:
            print(f"[run] {job.label}: skipped ({claim.reason})", flush=True)
            return {"label": job.label, "run_id": "", "status": "SKIPPED", "reason": claim.reason, "seconds": 0.0}
        with lease.Heartbeat(store, claim.run_id, self.lease_s) as beat, system_metrics(claim.run_id, self.uri):
            try:
                tracker = self._open_run(store, claim, job, cfg, dcfg, out_dir)
            except Exception as exc:  # the store failed under us: do not leave the claim RUNNING
                store.terminate(claim.run_id, "FAILED", {"failure": "harness", "error": f"{type(exc).__name__}: {exc}"})
                raise
            t0 = time.time()
            result: RunResult | None = None
            error: Exception | None = None
            try:
                result = (self.train_fn or _default_train)(cfg, out_dir, tracker)
            except Exception as exc:  # any crash is recorded, never lost
                error = exc
                (out_dir / "error.txt").write_text(traceback.format_exc())
                tracker.log_artifact(out_dir / "error.txt")
            except BaseException:  # Ctrl-C / SystemExit: the run was killed
                tracker.flush()
                store.terminate(tracker.run_id, "KILLED", {"failure": "interrupted", "error": "interrupted"})
                raise
            seconds = time.time() - t0
            status, extra = _outcome_tags(result, error)
            beat.stop()
            if not self._close_run(store, tracker, result, status, extra, seconds, cfg.iterations, out_dir):
                status, extra = "LOST", {"failure": "lease_lost", "error": "taken over by another invocation"}
        self._report(job, status, extra, result, seconds)
        return {"label": job.label, "run_id": tracker.run_id, "status": status, **extra, "seconds": seconds}

    def _open_run(self, store: Store, claim: lease.Claim, job: JobInfo, cfg: Any, dcfg: DictConfig,
                  out_dir: Path) -> MlflowTracker:
        """Fill the claimed child run: tags, params, the scene as a dataset input, the config."""
        assert claim.run_id is not None
        device = resolve_device(cfg.device)
        tags = {
            "mlflow.parentRunId": self.parent_run_id,
            **source_tags(self.command),
            "git_sha": git_sha(),
            "backend": resolve_backend(cfg.backend, device),
            "device": device,
            "out_dir": str(out_dir),
        }
        params = flatten_config(cfg)
        # joblib (loky) workers get cores / jobs torch threads: the params say what the run used,
        # the hash stays the planned one; only another difference is worth a warning
        if config_hash({**params, "threads": job.threads}, job.synth) != job.config_hash:
            actual = config_hash(params, job.synth)
            print(f"[run] {job.label}: warning: config hash {actual} differs from planned {job.config_hash}")
            tags["config_hash_actual"] = actual
        tracker = MlflowTracker(store, claim.run_id)
        tracker.set_tags(tags)
        tracker.log_params(params)
        store.log_inputs(claim.run_id, [scene_dataset(job.tags["scene"], cfg.data.path, cfg.data.format, job.synth)])
        config_file = out_dir / "config.yaml"
        config_file.write_text(OmegaConf.to_yaml(dcfg, resolve=True))
        tracker.log_artifact(config_file)
        took = f", took over {', '.join(r[:8] for r in claim.took_over)}" if claim.took_over else ""
        print(f"[run] {job.label}: started (child run {tracker.run_id[:8]}{took}, outputs in {out_dir})", flush=True)
        return tracker

    @staticmethod
    def _close_run(store: Store, tracker: MlflowTracker, result: RunResult | None, status: str,
                   extra: dict[str, str], seconds: float, iterations: int, out_dir: Path) -> bool:
        """Final metrics and artifacts the trainer did not log itself, then the status.

        Returns False (and leaves the run alone) if another invocation took the run over
        while this worker was silent for longer than its lease.
        """
        tracker.flush()
        if result is not None:
            final = {k: v for k, v in result.metrics.items() if k not in tracker.metric_keys}
            if "train_seconds" not in tracker.metric_keys:
                final.setdefault("train_seconds", seconds)
            tracker.log_metrics(final, step=iterations)
            tracker.flush()
            for path in result.artifacts:
                if Path(path).resolve() not in tracker.logged_artifacts:
                    tracker.log_artifact(path, _artifact_subdir(Path(path), out_dir))
        if store.status(tracker.run_id) != "RUNNING":
            return False
        store.terminate(tracker.run_id, status, extra)
        return True

    def _report(self, job: JobInfo, status: str, extra: dict[str, str], result: RunResult | None,
                seconds: float) -> None:
        """One progress line for the run and the whole study."""
        prog = progress.record(Path(self.progress_path), job.label, status, len(self.jobs), self.started_at)
        psnr = result.metrics.get("psnr") if result is not None else None
        what = status if not extra else f"{status} ({extra['failure']}: {extra['error'][:120]})"
        psnr_txt = f" psnr={psnr:.2f}" if isinstance(psnr, (int, float)) else ""
        print(f"[{prog.done}/{prog.total}] {job.label}: {what}{psnr_txt} in {progress.fmt_seconds(seconds)}"
              f" | {prog.line()}", flush=True)


# --- the whole study ---------------------------------------------------------------------


def _key(p: PlannedRun) -> tuple[str, str, int, str]:
    return (p.spec.variant, p.spec.scene.name, p.spec.seed, p.config_hash)


def pending(store: Store, experiment: str, study: str, planned: list[PlannedRun],
            lease_s: float = lease.DEFAULT_LEASE_S) -> tuple[list[PlannedRun], list[RunRecord]]:
    """(planned runs to launch, live claims of other invocations that are left to them).

    A run is launched unless it FINISHED or a live worker holds it; stale RUNNING runs are
    taken over by the job that claims the run (``harness.lease.acquire``), not here.
    """
    existing = load_runs(store, experiment, study)
    done = {r.key for r in existing if r.status == "FINISHED"}
    live = {r.key: r for r in existing if lease.is_live(r, lease_s) and r.key not in done}
    todo = [p for p in planned if _key(p) not in done and _key(p) not in live]
    keys = {_key(p) for p in planned}
    return todo, [r for k, r in live.items() if k in keys]


def foreign_domain_notes(store: Store, experiment: str, study: str, planned: list[PlannedRun]) -> list[str]:
    """One line per finished run that counts as done here although its bits come from another
    determinism domain than this machine would give it (or from no recorded one)."""
    from ftgspp.determinism import expected_domain_id

    by_key = {_key(p): p for p in planned}
    expected: dict[tuple[str, int, str], str | None] = {}
    notes = []
    for rec in load_runs(store, experiment, study):
        p = by_key.get(rec.key)
        if rec.status != "FINISHED" or p is None:
            continue
        settings = (p.params.get("determinism", "default"), int(p.params.get("threads", "0")),
                    p.params.get("dispatch", "native"))
        if settings not in expected:
            expected[settings] = expected_domain_id(*settings)
        here, got = expected[settings], rec.tags.get("determinism.id", "")
        if here is not None and got != here:
            notes.append(f"[resume] {p.spec.label}: finished in determinism domain {got or 'unrecorded'}, this machine"
                         f" gives {here}; counted as done (its numbers need not match a run here bit for bit)")
    return notes


def _open_parent(store: Store, exp_id: str, study: StudySpec, sel: Selection, jobs: int, launcher: str,
                 launcher_args: list[str], command: str, planned: list[PlannedRun],
                 todo: list[PlannedRun]) -> tuple[str, str]:
    """The invocation's parent run (tags, params, the study file); returns (run id, stamp)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    tags = {
        "study": study.name,
        "profile": sel.profile,
        "kind": "study",
        "invocation": json.dumps({**asdict(sel), "jobs": jobs, "launcher": launcher,
                                  "launcher_overrides": launcher_args}),
        "command": command,
        **source_tags(command),
        "git_sha": git_sha(),
        "n_runs": str(len(planned)),
        "n_launched": str(len(todo)),
    }
    parent_id = store.create_run(exp_id, f"{study.name}-{sel.profile}-{stamp}", tags)
    n_seeds = len({p.spec.seed for p in planned})
    store.log_batch(parent_id, params={"profile": sel.profile, "jobs": jobs, "launcher": launcher,
                                       "seeds": n_seeds, "base_seed": study.base_seed})
    # the study's scenes as dataset inputs: the runs table shows them on the parent's row
    scenes = {p.spec.scene.name: p for p in todo}.values()
    store.log_inputs(parent_id, [scene_dataset(p.spec.scene.name, p.params["data.path"], p.params["data.format"],
                                               p.spec.scene.synth) for p in scenes])
    if study.path is not None:  # the study definition this invocation used
        store.log_artifact(parent_id, study.path)
    return parent_id, stamp


@contextlib.contextmanager
def _scene_lock(scene: SceneSpec) -> Iterator[None]:
    """An exclusive ``fcntl`` lock on ``<scene folder>.lock`` (synthetic scenes only)."""
    if scene.synth is None:
        yield
        return
    lock = Path(scene.synth_dir).with_name(Path(scene.synth_dir).name + ".lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    with open(lock, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


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
) -> StudyOutcome:
    """Run the missing or failed runs of study ``name``; see the module docstring."""
    if jobs < 1:
        raise InputError("--jobs", "must be at least 1")
    try:
        lease_s = lease.lease_seconds(lease_s)
    except ValueError as exc:
        raise InputError("--lease", str(exc)) from None
    study = load_study(name, studies_dir)
    command = command_line(name, sel, jobs, launcher)
    run_overrides, launcher_args = split_launcher_args(sel.overrides)
    sel = dataclasses.replace(sel, overrides=run_overrides)
    planned = plan_runs(expand(study, sel))  # every bad input stops here ...
    uri, exp_name = tracking_target(sel, planned)
    check_launcher(launcher, uri)
    check_launcher_args(launcher, launcher_args, Path(out_root).resolve())
    check_store(uri)  # ... or here, before anything is written

    store = Store(uri)
    exp_id = store.experiment_id(exp_name)  # created once, before any worker starts
    assert exp_id is not None
    todo, elsewhere = pending(store, exp_name, name, planned, lease_s)
    for line in foreign_domain_notes(store, exp_name, name, planned):
        echo(line)
    outcome = StudyOutcome(total=len(planned), skipped=len(planned) - len(todo), launched=len(todo))
    n_done = outcome.skipped - len(elsewhere)
    echo(f"{name} ({sel.profile}): {describe_runs([p.spec for p in planned])};"
         f" {n_done} already finished, " + (f"{len(elsewhere)} running elsewhere, " if elsewhere else "")
         + f"{len(todo)} to run"
         + (f" with {jobs} parallel jobs" if jobs > 1 and todo else "")
         + (f" through the {launcher} launcher" if launcher != "basic" and todo else ""))
    for rec in elsewhere:
        echo(f"  running elsewhere: {rec.tags.get('mlflow.runName', rec.key)} ({lease.describe(rec)})")
    if not todo:
        return outcome

    for scene in {p.spec.scene.name: p.spec.scene for p in todo}.values():
        with _scene_lock(scene):  # another invocation may be generating it right now
            ensure_scene(scene, generate, echo)
    parent_id, stamp = _open_parent(store, exp_id, study, sel, jobs, launcher, launcher_args, command, planned, todo)
    outcome.parent_run_id = parent_id
    # absolute: submitit's folder lives under it and jobs on other nodes must find it
    sweep_dir = (Path(out_root) / name / f"{stamp}-{parent_id[:8]}").resolve()
    task = RunTask(
        uri=uri,
        experiment_id=exp_id,
        parent_run_id=parent_id,
        jobs=[JobInfo(p.spec.label, p.tags, p.config_hash, p.spec.scene.synth, p.params.get("threads", ""))
              for p in todo],
        progress_path=str(sweep_dir / "progress.jsonl"),
        started_at=time.time(),
        train_fn=train_fn,
        lease_s=lease_s,
        command=command,
    )
    # progress bars of parallel workers would interleave (progress is not part of the hash)
    quiet = ["progress=false"] if jobs > 1 or launcher in ("local", "slurm") else []
    job_overrides = [[*p.spec.overrides, *quiet, f"hydra.sweep.subdir={p.spec.label}"] for p in todo]
    try:
        returns = launch(job_overrides, task, sweep_dir=sweep_dir, jobs=jobs, job_name=f"study_{name}",
                         launcher=launcher, launcher_args=launcher_args)
        _tally(outcome, todo, returns)
    except Exception as exc:  # e.g. submitit's UncompletedJobError: a job died without returning
        if launcher not in ("local", "slurm"):
            store.terminate(parent_id, "FAILED", {"error": f"{type(exc).__name__}: {exc}"[:1000]})
            raise
        _tally_from_store(outcome, store, exp_name, name, parent_id, exc)
    except BaseException as exc:
        status = "KILLED" if isinstance(exc, KeyboardInterrupt) else "FAILED"
        store.terminate(parent_id, status, {"error": f"{type(exc).__name__}: {exc}"[:1000]})
        raise
    store.terminate(parent_id, "FINISHED", {"n_finished": str(outcome.finished), "n_failed": str(outcome.failed),
                                            "n_diverged": str(outcome.diverged),
                                            "n_claimed_elsewhere": str(outcome.claimed_elsewhere)})
    elsewhere_txt = f", {outcome.claimed_elsewhere} claimed by other invocations" if outcome.claimed_elsewhere else ""
    echo(f"{name}: {outcome.finished} finished, {outcome.failed} failed ({outcome.diverged} diverged),"
         f" {outcome.skipped} skipped{elsewhere_txt}; parent run {parent_id} in {exp_name} at {uri}")
    echo(f"browse: {ui_link(uri, exp_id)}")
    return outcome


def ui_link(uri: str, experiment_id: str) -> str:
    """Where the experiment's runs table is in the MLflow UI.

    MLflow 3.17's UI opens every experiment in the GenAI view unless the browser chose
    "Model training" before (it ignores ``mlflow.experimentKind`` there); the
    ``workflowType`` parameter selects the training-runs view.
    """
    page = f"#/experiments/{experiment_id}/runs?workflowType=machine_learning"
    if uri.startswith(("http://", "https://")):
        return f"{uri.rstrip('/')}/{page}"
    return f"mlflow ui --backend-store-uri {uri}, then http://127.0.0.1:5000/{page}"
