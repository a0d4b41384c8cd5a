"""One child run of a study, inside its job (possibly a joblib worker or a node of a cluster).

``RunTask`` is the Hydra task function: it claims the child run (a lease kept fresh by a
heartbeat; ``run.lease``), fills it (tags, params, the scene as a dataset input, the
resolved config), trains through ``run.training.run_training`` with an ``MlflowTracker``,
logs what the trainer did not, and ends the run FINISHED, or FAILED with ``failure`` =
diverged | input_error | crashed and the error in ``error``. A run claimed elsewhere in the
meantime comes back ``SKIPPED``. A run stopped by Ctrl-C, SIGTERM or SIGHUP (``run.stopping``)
ends KILLED with ``failure=interrupted`` and the signal in ``stop_signal``, after the tracker has
written what the trainer logged; a worker once stopped starts no further run.
"""

from __future__ import annotations

import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from omegaconf import DictConfig, OmegaConf

from ftgspp.errors import InputError
from ftgspp.tracker import RunResult
from harness.run import lease, progress, runlog, stopping
from harness.spec.confighash import config_hash, flatten_config
from harness.spec.plan import resolve
from harness.tracking.conventions import run_name, scene_dataset, source_tags, system_metrics
from harness.tracking.mlflow_tracker import MlflowTracker
from harness.tracking.provenance import git_sha, resolve_backend, resolve_device, trainer_fingerprint
from harness.tracking.store import Store

TrainFn = Callable[..., RunResult]  # (cfg: TrainConfig, out_dir: Path, tracker) -> RunResult
_STORES: dict[str, Store] = {}  # one per tracking URI and worker process


@dataclass(frozen=True)
class JobInfo:
    """What a worker needs to know about its run besides the composed config."""

    label: str
    tags: dict[str, str]
    config_hash: str
    synth: dict[str, Any] | None = None  # synthetic scene args (part of the hash)
    threads: str = ""  # torch threads the plan assumed (a joblib worker may get fewer)




def _store(uri: str) -> Store:
    if uri not in _STORES:
        _STORES[uri] = Store(uri)
    return _STORES[uri]


def _default_train(cfg: Any, out_dir: Path, tracker: Any) -> RunResult:
    from harness.run import training  # looked up at call time so tests can monkeypatch it

    return training.run_training(cfg, out_dir, tracker)


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


def _end_killed(store: Store, run_id: str, exc: BaseException) -> None:
    """End a claimed run KILLED with the stop's tags, unless it has ended already; a store that
    fails now is left to the study process, which ends what its workers left RUNNING."""
    try:
        if store.status(run_id) == "RUNNING":
            store.terminate(run_id, "KILLED", stopping.killed_tags(exc))
    except Exception:
        pass


def _killed(store: Store, tracker: MlflowTracker, label: str, log: Path, exc: BaseException) -> None:
    """A run stopped while it trained: what the trainer logged so far is written, the run ends KILLED."""
    why = stopping.killed_tags(exc)["error"]
    with open(log, "a") as fh:
        fh.write(f"[run] {label}: {why}\n")
    try:
        tracker.flush()
    finally:
        _end_killed(store, tracker.run_id, exc)
    print(f"[run] {label}: KILLED ({why})", flush=True)


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
    expected_total_s: float = 0.0  # the profile's estimate for the launched runs (ETA until runs finish)
    train_fn: TrainFn | None = None
    lease_s: float = lease.DEFAULT_LEASE_S
    command: str = ""
    trainer: str = ""  # the trainer fingerprint a finished run must have to count as done ("": any)

    def __call__(self, dcfg: DictConfig) -> dict[str, Any]:
        # in a worker's main thread SIGTERM/SIGHUP/SIGINT stop the run as Ctrl-C does (run.stopping);
        # in the study process (basic launcher) the study's own handlers are already on
        with stopping.on_signals():
            if (signum := stopping.received()) is not None:  # this worker is stopping: no new run
                raise stopping.Stopped(signum)
            return self._run(dcfg)

    def _run(self, dcfg: DictConfig) -> dict[str, Any]:
        from hydra.core.hydra_config import HydraConfig

        hydra_cfg = HydraConfig.get()
        job = self.jobs[int(hydra_cfg.job.num)]
        out_dir = Path(hydra_cfg.runtime.output_dir)
        cfg = resolve(dcfg, job.label)
        store = _store(self.uri)
        claim = lease.acquire(store, self.experiment_id, run_name(job.label, job.tags["profile"]),
                              {**job.tags, "kind": "run", "mlflow.parentRunId": self.parent_run_id}, self.lease_s,
                              trainer=self.trainer)
        if claim.run_id is None:
            print(f"[run] {job.label}: skipped ({claim.reason})", flush=True)
            return {"label": job.label, "run_id": "", "status": "SKIPPED", "reason": claim.reason, "seconds": 0.0}
        try:
            return self._claimed(store, claim, job, cfg, dcfg, out_dir, hydra_cfg)
        except (KeyboardInterrupt, SystemExit) as exc:  # stopped anywhere after the claim: the run was killed
            _end_killed(store, claim.run_id, exc)
            raise

    def _claimed(self, store: Store, claim: lease.Claim, job: JobInfo, cfg: Any, dcfg: DictConfig, out_dir: Path,
                 hydra_cfg: Any) -> dict[str, Any]:
        """Train the claimed run and record its outcome."""
        assert claim.run_id is not None
        with lease.Heartbeat(store, claim.run_id, self.lease_s) as beat, system_metrics(claim.run_id, self.uri):
            try:
                tracker = self._open_run(store, claim, job, cfg, dcfg, out_dir)
            except Exception as exc:  # the store failed under us: do not leave the claim RUNNING
                store.terminate(claim.run_id, "FAILED", {"failure": "harness", "error": f"{type(exc).__name__}: {exc}"})
                raise
            t0 = time.time()
            result: RunResult | None = None
            error: Exception | None = None
            log = out_dir / f"{hydra_cfg.job.name}.log"  # also Hydra's job log file (run.runlog)
            try:
                with runlog.capture(log, job.label, f"job #{hydra_cfg.job.num}: {' '.join(hydra_cfg.overrides.task)}"):
                    result = (self.train_fn or _default_train)(cfg, out_dir, tracker)
            except Exception as exc:
                if (signum := stopping.received()) is not None:  # the stop, turned into another error by a
                    stop = stopping.Stopped(signum)               # Numba kernel or autograd it passed through
                    _killed(store, tracker, job.label, log, stop)
                    raise stop from exc
                error = exc  # any crash is recorded, never lost
                (out_dir / "error.txt").write_text(traceback.format_exc())
                with open(log, "a") as fh:
                    fh.write(traceback.format_exc())
                tracker.log_artifact(out_dir / "error.txt")
            except BaseException as exc:  # Ctrl-C, SIGTERM, SIGHUP (run.stopping), SystemExit: the run was killed
                _killed(store, tracker, job.label, log, exc)
                raise
            seconds = time.time() - t0
            status, extra = _outcome_tags(result, error)
            beat.stop()
            if not self._close_run(store, tracker, result, status, extra, seconds, cfg.iterations, out_dir):
                status, extra = "LOST", {"failure": "lease_lost", "error": "taken over by another invocation"}
        self._report(job, status, extra, result, seconds, log)
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
            "trainer_fingerprint": trainer_fingerprint(),
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
        print(f"[run] {job.label}: started (child run {tracker.run_id[:8]}{took})", flush=True)
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
                seconds: float, log: Path) -> None:
        """One progress line for the run and the whole study (a failed run's names its log)."""
        prog = progress.record(Path(self.progress_path), job.label, status, len(self.jobs), self.started_at,
                               self.expected_total_s)
        psnr = result.metrics.get("psnr") if result is not None else None
        what = status if not extra else f"{status} ({extra['failure']}: {extra['error'][:120]}; log: {log})"
        psnr_txt = f" psnr={psnr:.2f}" if isinstance(psnr, (int, float)) else ""
        print(f"[{prog.done}/{prog.total}] {job.label}: {what}{psnr_txt} in {progress.fmt_seconds(seconds)}"
              f" | {prog.line()}", flush=True)
