"""Start a study's joblib workers while the study process still prepares its runs.

Hydra's joblib launcher runs jobs in joblib's reusable loky executor, whose workers are
spawned when the launcher first calls ``joblib.Parallel``; each then spends seconds importing
torch, Numba's cached kernels, Hydra and MLflow before its first run starts. ``prewarm``
starts that executor early, from a thread, with the arguments the launcher will use, and has
each worker import what a run needs and load the kernels. The study process meanwhile opens
the tracking store and generates scenes (mostly one core), so the two overlap; the
launcher then reuses the same workers (joblib reuses its executor when the arguments
match; with other ``hydra.launcher.*`` arguments it would start new ones, so ``prewarm`` is
not used then).

Nothing a run computes depends on this: the kernels are called on tiny inputs with torch's
random state saved and restored, and every run seeds its own generators. A failed warm-up is
reported in one line and the launcher starts workers of its own. A study with nothing left
to run waits for the warm-up before it exits (a few seconds).
"""

from __future__ import annotations

import dataclasses
import os
import threading
from typing import Any

from harness.run.launchers import effective_launcher

# what a job imports before its run starts (run.task and the trainer behind it)
RUN_MODULES = ("harness.run.task", "harness.run.training", "ftgspp.trainer", "ftgspp.data.load",
               "ftgspp.diagnostics.diagnose", "ftgspp.evaluate", "mlflow")


def _warm_worker() -> int:
    """In a worker: import what a run needs and, when Numba's cache holds them, load the cpu
    kernels; returns the worker's pid."""
    import importlib

    for name in RUN_MODULES:
        importlib.import_module(name)
    import torch

    from ftgspp.bench.warmup import kernels_cached, warm_up

    if kernels_cached():  # else the study compiles them once (runner.warm_kernels), not every worker
        with torch.random.fork_rng(devices=[]):  # the warm-up's random inputs leave no trace
            warm_up()
    return os.getpid()


def joblib_arguments(jobs: int) -> dict[str, Any]:
    """``joblib.Parallel``'s arguments as Hydra's joblib launcher passes them (its defaults)."""
    from hydra_plugins.hydra_joblib_launcher._core import process_joblib_cfg
    from hydra_plugins.hydra_joblib_launcher.config import JobLibLauncherConf

    args = dataclasses.asdict(JobLibLauncherConf(n_jobs=jobs))
    args.pop("_target_")
    args["backend"] = "loky"  # as the launcher sets it
    process_joblib_cfg(args)
    return args


class Prewarm:
    """The warm-up of ``jobs`` workers, running in a thread; ``wait()`` before launching."""

    def __init__(self, jobs: int):
        self.jobs = jobs
        self.pids: list[int] = []
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="prewarm-workers", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            from joblib import Parallel, delayed

            self.pids = Parallel(**joblib_arguments(self.jobs))(delayed(_warm_worker)() for _ in range(self.jobs))
        except BaseException as exc:  # the launcher starts its own workers then, and reports any real problem
            self.error = exc

    def wait(self) -> None:
        """Block until every worker is warm (or the warm-up failed)."""
        self._thread.join()


def prewarm(launcher: str, jobs: int, launcher_args: list[str]) -> Prewarm | None:
    """Warm ``jobs`` joblib workers in the background when the study will run through them."""
    if effective_launcher(launcher, jobs) != "joblib" or jobs < 2 or launcher_args:
        return None
    return Prewarm(jobs)
