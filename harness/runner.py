"""Run a study: expand, skip what already finished, launch the rest, record every outcome.

``run_study`` is what ``study run`` calls:

1. expand the study file into runs (variant x scene x seed) and compose every run's
   config (``harness.plan``) - bad overrides stop here, before the store is touched;
2. check the tracking store, find runs already FINISHED with the same (study, variant,
   scene, seed, config_hash) and skip them; child runs left RUNNING by a killed
   invocation are marked FAILED (``failure=interrupted``);
3. generate missing synthetic scenes, open one MLflow parent run, and launch the rest
   through a Hydra launcher (``harness.launch``; basic, or joblib for ``jobs > 1``);
4. each job (``RunTask``, also in worker processes) opens its child run, trains through
   ``harness.train_app.run_training`` with an ``MlflowTracker``, and ends the run FINISHED,
   or FAILED with ``failure`` = diverged | input_error | crashed and the error in ``error``.
"""

from __future__ import annotations

import json
import shlex
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from omegaconf import DictConfig, OmegaConf

from ftgspp.errors import InputError
from ftgspp.tracking import RunResult
from harness import progress
from harness.confighash import config_hash, flatten_config
from harness.launch import launch
from harness.plan import PlannedRun, plan_runs, resolve
from harness.provenance import git_sha, resolve_backend, resolve_device
from harness.records import experiment_name, load_runs
from harness.scenes import Generator, ensure_scene
from harness.studies import Selection, StudySpec, expand, load_study
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


@dataclass
class StudyOutcome:
    """What one ``study run`` did."""

    total: int
    skipped: int
    launched: int
    finished: int = 0
    failed: int = 0
    diverged: int = 0
    parent_run_id: str = ""
    results: list[dict[str, Any]] = field(default_factory=list)


def command_line(study: str, sel: Selection, jobs: int = 1) -> str:
    """The ``study run`` command that reproduces an invocation."""
    parts = ["study", "run", study, "--profile", sel.profile]
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
    """Hydra task function: one child run. Picklable, so joblib workers can run it."""

    uri: str
    experiment_id: str
    parent_run_id: str
    jobs: list[JobInfo]
    progress_path: str
    started_at: float
    train_fn: TrainFn | None = None

    def __call__(self, dcfg: DictConfig) -> dict[str, Any]:
        from hydra.core.hydra_config import HydraConfig

        hydra_cfg = HydraConfig.get()
        job = self.jobs[int(hydra_cfg.job.num)]
        out_dir = Path(hydra_cfg.runtime.output_dir)
        cfg = resolve(dcfg, job.label)
        store = _store(self.uri)
        tracker = self._open_run(store, job, cfg, dcfg, out_dir)
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
        self._close_run(store, tracker, result, status, extra, seconds, cfg.iterations, out_dir)
        self._report(job, status, extra, result, seconds)
        return {"label": job.label, "run_id": tracker.run_id, "status": status, **extra, "seconds": seconds}

    def _open_run(self, store: Store, job: JobInfo, cfg: Any, dcfg: DictConfig, out_dir: Path) -> MlflowTracker:
        """Create the child run with its tags, params and resolved config."""
        device = resolve_device(cfg.device)
        tags = {
            **job.tags,
            "kind": "run",
            "mlflow.parentRunId": self.parent_run_id,
            "git_sha": git_sha(),
            "backend": resolve_backend(cfg.backend, device),
            "device": device,
            "out_dir": str(out_dir),
        }
        params = flatten_config(cfg)
        actual = config_hash(params, job.synth)
        if actual != job.config_hash:  # the launcher's full composition disagrees with the plan
            print(f"[run] {job.label}: warning: config hash {actual} differs from planned {job.config_hash}")
            tags["config_hash_actual"] = actual
        tracker = MlflowTracker(store, store.create_run(self.experiment_id, job.label, tags))
        tracker.log_params(params)
        config_file = out_dir / "config.yaml"
        config_file.write_text(OmegaConf.to_yaml(dcfg, resolve=True))
        tracker.log_artifact(config_file)
        print(f"[run] {job.label}: started (child run {tracker.run_id[:8]}, outputs in {out_dir})", flush=True)
        return tracker

    @staticmethod
    def _close_run(store: Store, tracker: MlflowTracker, result: RunResult | None, status: str,
                   extra: dict[str, str], seconds: float, iterations: int, out_dir: Path) -> None:
        """Final metrics and artifacts the trainer did not log itself, then the status."""
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
        store.terminate(tracker.run_id, status, extra)

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


def pending(store: Store, experiment: str, study: str, planned: list[PlannedRun]) -> list[PlannedRun]:
    """Planned runs without a FINISHED record; RUNNING leftovers of killed invocations become FAILED."""
    existing = load_runs(store, experiment, study)
    keys = {_key(p) for p in planned}
    for rec in existing:
        if rec.status == "RUNNING" and rec.key in keys:
            store.terminate(rec.run_id, "FAILED", {"failure": "interrupted",
                                                   "error": "run was killed (found RUNNING on resume)"})
    done = {r.key for r in existing if r.status == "FINISHED"}
    return [p for p in planned if _key(p) not in done]


def _open_parent(store: Store, exp_id: str, study: StudySpec, sel: Selection, jobs: int,
                 planned: list[PlannedRun], todo: list[PlannedRun]) -> tuple[str, str]:
    """The invocation's parent run (tags, params, the study file); returns (run id, stamp)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    tags = {
        "study": study.name,
        "profile": sel.profile,
        "kind": "study",
        "invocation": json.dumps({**asdict(sel), "jobs": jobs}),
        "command": command_line(study.name, sel, jobs),
        "git_sha": git_sha(),
        "n_runs": str(len(planned)),
        "n_launched": str(len(todo)),
    }
    parent_id = store.create_run(exp_id, f"{study.name}-{sel.profile}-{stamp}", tags)
    n_seeds = len({p.spec.seed for p in planned})
    store.log_batch(parent_id, params={"profile": sel.profile, "jobs": jobs, "seeds": n_seeds,
                                       "base_seed": study.base_seed})
    if study.path is not None:  # the study definition this invocation used
        store.log_artifact(parent_id, study.path)
    return parent_id, stamp


def _tally(outcome: StudyOutcome, todo: list[PlannedRun], returns: list[Any]) -> None:
    for run, ret in zip(todo, returns):
        try:
            res = ret.return_value
        except Exception as exc:  # the task itself failed (e.g. a tracking store error)
            res = {"label": run.spec.label, "status": "FAILED", "failure": "harness", "error": str(exc)}
        outcome.results.append(res)
        if res["status"] == "FINISHED":
            outcome.finished += 1
        else:
            outcome.failed += 1
            outcome.diverged += res.get("failure") == "diverged"


def run_study(
    name: str,
    sel: Selection,
    *,
    jobs: int = 1,
    studies_dir: Path | None = None,
    out_root: Path = OUT_ROOT,
    train_fn: TrainFn | None = None,
    generate: Generator | None = None,
    echo: Callable[[str], None] = print,
) -> StudyOutcome:
    """Run the missing or failed runs of study ``name``; see the module docstring."""
    if jobs < 1:
        raise InputError("--jobs", "must be at least 1")
    study = load_study(name, studies_dir)
    planned = plan_runs(expand(study, sel))  # every bad input stops here ...
    uri, exp_name = tracking_target(sel, planned)
    check_store(uri)  # ... or here, before anything is written

    store = Store(uri)
    exp_id = store.experiment_id(exp_name)
    assert exp_id is not None
    todo = pending(store, exp_name, name, planned)
    outcome = StudyOutcome(total=len(planned), skipped=len(planned) - len(todo), launched=len(todo))
    n_var, n_scene, n_seed = (len(set(x)) for x in zip(*(p.spec.key for p in planned)))
    echo(f"{name} ({sel.profile}): {len(planned)} runs = {n_var} variants x {n_scene} scenes x {n_seed} seeds;"
         f" {outcome.skipped} already finished, {len(todo)} to run"
         + (f" with {jobs} parallel jobs" if jobs > 1 and todo else ""))
    if not todo:
        return outcome

    for scene in {p.spec.scene.name: p.spec.scene for p in todo}.values():
        ensure_scene(scene, generate, echo)
    parent_id, stamp = _open_parent(store, exp_id, study, sel, jobs, planned, todo)
    outcome.parent_run_id = parent_id
    sweep_dir = Path(out_root) / name / f"{stamp}-{parent_id[:8]}"
    task = RunTask(
        uri=uri,
        experiment_id=exp_id,
        parent_run_id=parent_id,
        jobs=[JobInfo(p.spec.label, p.tags, p.config_hash, p.spec.scene.synth) for p in todo],
        progress_path=str(sweep_dir / "progress.jsonl"),
        started_at=time.time(),
        train_fn=train_fn,
    )
    # progress bars of parallel workers would interleave (progress is not part of the hash)
    quiet = ["progress=false"] if jobs > 1 else []
    job_overrides = [[*p.spec.overrides, *quiet, f"hydra.sweep.subdir={p.spec.label}"] for p in todo]
    try:
        returns = launch(job_overrides, task, sweep_dir=sweep_dir, jobs=jobs, job_name=f"study_{name}")
    except BaseException as exc:
        status = "KILLED" if isinstance(exc, KeyboardInterrupt) else "FAILED"
        store.terminate(parent_id, status, {"error": f"{type(exc).__name__}: {exc}"[:1000]})
        raise
    _tally(outcome, todo, returns)
    store.terminate(parent_id, "FINISHED", {"n_finished": str(outcome.finished), "n_failed": str(outcome.failed),
                                            "n_diverged": str(outcome.diverged)})
    echo(f"{name}: {outcome.finished} finished, {outcome.failed} failed ({outcome.diverged} diverged),"
         f" {outcome.skipped} skipped; parent run {parent_id} in {exp_name} at {uri}")
    return outcome
