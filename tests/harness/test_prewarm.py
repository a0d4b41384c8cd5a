"""Warm joblib workers (``run.prewarm``): used only where the joblib launcher will run the jobs,
and the launcher's jobs then run in the very workers that were warmed."""

from __future__ import annotations

import os
from pathlib import Path

from omegaconf import DictConfig

from harness.run.launchers import launch
from harness.run.prewarm import Prewarm, prewarm


def _pid(cfg: DictConfig) -> int:
    return os.getpid()


def test_prewarm_only_for_the_joblib_launcher_with_its_own_arguments() -> None:
    assert prewarm("basic", 1, []) is None  # in-process: no workers
    assert prewarm("local", 2, []) is None and prewarm("slurm", 2, []) is None
    assert prewarm("joblib", 2, ["hydra.launcher.timeout=60"]) is None  # other arguments: other workers


def test_the_launcher_runs_its_jobs_in_the_warmed_workers(tmp_path: Path) -> None:
    warm = prewarm("basic", 2, [])  # --jobs 2 switches basic to joblib
    assert isinstance(warm, Prewarm)
    warm.wait()
    assert warm.error is None and len(set(warm.pids)) == 2 and os.getpid() not in warm.pids
    try:
        returns = launch([["seed=0"], ["seed=1"], ["seed=2"]], _pid, sweep_dir=tmp_path / "sweep", jobs=2)
        assert {r.return_value for r in returns} <= set(warm.pids)
    finally:  # the workers hold torch and MLflow: end them now rather than at loky's idle timeout
        from joblib.externals.loky import reusable_executor

        if reusable_executor._executor is not None:
            reusable_executor._executor.shutdown(wait=True, kill_workers=True)
