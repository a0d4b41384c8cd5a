"""Which Hydra launcher runs a study's jobs, whether it can run here, and ``launch``.

``study run --launcher NAME``:

- ``basic``: Hydra's in-process launcher, one run after another (``--jobs N`` > 1 switches
  to ``joblib``);
- ``joblib``: ``--jobs`` worker processes on this machine;
- ``local``: submitit's local executor (``conf/hydra/launcher/local.yaml``), one process per
  run - a dry run of the SLURM path on one machine. Its executor starts every job it is given
  at once, with no cap, so ``launch`` hands it one job at a time from ``jobs`` threads: at most
  ``jobs`` runs are alive at once (``study run`` without ``--jobs``: ``local_slots``, one per
  core and as many as fit in the available memory);
- ``slurm``: submitit's SLURM executor (``conf/hydra/launcher/slurm.yaml``: partition, time
  limit, GPUs, CPUs, memory, array parallelism, site setup lines); one job array.

The released ``hydra-submitit-launcher`` 1.2.0 works unchanged with Python 3.11 and
hydra-core 1.3 (checked by ``tests/harness/test_study_launchers.py``); no shim. Its one
weakness for us - when a job dies without returning (killed, node lost, time limit) its
``launch`` raises for the whole array - is handled by the runner, which then counts the
runs from the tracking store, where every run records itself.

``check_launcher`` turns a launcher that cannot work into one ``InputError`` line before
anything is written: ``sbatch`` missing, or a SQLite file store with SLURM (jobs on other
nodes cannot share a SQLite file safely; they need ``mlflow server``), or a
``hydra.launcher.KEY=VALUE`` override the chosen launcher does not have. Those overrides
(``split_launcher_args``) configure the launcher, not the runs: they are not part of any
run's config or hash.

Every launch logs through ``conf/hydra/{hydra_logging,job_logging}/study.yaml`` (``run.runlog``):
Hydra's launcher lines go to ``launcher.log`` in the sweep folder, a run's log records to its
own log file, and only warnings to the terminal.
"""

from __future__ import annotations

import os
import shutil
import threading
from pathlib import Path
from typing import Any, Callable, Sequence

from omegaconf import DictConfig

from ftgspp.errors import InputError
from harness.spec.plan import error_line
from harness.spec.schema import CONF_DIR, register
from harness.tracking.store import sqlite_path

TaskFunction = Callable[[DictConfig], Any]
_STOP = threading.Event()  # set while the study stops (run.stopping): ``_at_most`` starts no further job


def stop_launching() -> None:
    """Start no further job of the ``launch`` in progress (the study is being stopped)."""
    _STOP.set()

LAUNCHERS = ("basic", "joblib", "local", "slurm")  # also the config names in conf/hydra/launcher
SERVER_HINT = "start a tracking server (make server; docs/cluster.md) and pass tracking=server or tracking.uri=..."


def check_launcher(launcher: str, uri: str) -> None:
    """Raise ``InputError`` if ``launcher`` is unknown or cannot run with this store here."""
    if launcher not in LAUNCHERS:
        raise InputError("--launcher", f"unknown launcher '{launcher}' (choose from {', '.join(LAUNCHERS)})")
    if launcher in ("local", "slurm"):
        try:
            import hydra_plugins.hydra_submitit_launcher  # noqa: F401
            import submitit  # noqa: F401
        except ImportError:
            raise InputError("--launcher", f"{launcher} needs hydra-submitit-launcher and submitit "
                             "(pip install hydra-submitit-launcher submitit)") from None
    if launcher == "slurm":
        if shutil.which("sbatch") is None:
            raise InputError("--launcher slurm", "sbatch not found on PATH (run on a SLURM login node,"
                             " or use --launcher local)")
        if sqlite_path(uri) is not None:
            raise InputError("--launcher slurm", f"jobs on other nodes cannot share the SQLite store {uri};"
                             f" {SERVER_HINT}")


LAUNCHER_PREFIX = "hydra.launcher."


def split_launcher_args(overrides: list[str]) -> tuple[list[str], list[str]]:
    """(run overrides, ``hydra.launcher.*`` overrides) of a ``study run`` command line."""
    ours = [o for o in overrides if o.startswith(LAUNCHER_PREFIX)]
    return [o for o in overrides if not o.startswith(LAUNCHER_PREFIX)], ours


def check_launcher_args(launcher: str, args: list[str], sweep_dir: Path) -> None:
    """Compose the launcher's config with ``args``; one ``InputError`` line if it does not."""
    if not args:
        return
    from hydra import compose, initialize_config_dir

    register()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            compose("train", [*launcher_overrides(launcher, sweep_dir, 2, "check"), *args], return_hydra_config=True)
    except Exception as exc:  # unknown key or wrong type for this launcher
        raise InputError(" ".join(args), f"not valid for --launcher {launcher} ({error_line(exc)})") from None


def effective_launcher(launcher: str, jobs: int) -> str:
    """The launcher that runs the jobs: ``basic`` with ``jobs`` > 1 is ``joblib``."""
    return "joblib" if launcher == "basic" and jobs > 1 else launcher


RUN_MEMORY_GB = 1.2  # a quick run's trainer at its peak (about 1.1 GB seen; peak RSS 0.85-1.0 GB, BENCHMARKS history)


def local_slots(cores: int | None = None, available_gb: float | None = None) -> int:
    """How many runs ``--launcher local`` runs at once when ``--jobs`` is not given: one per
    core, and no more than fit in the memory available now at ``RUN_MEMORY_GB`` a run."""
    if available_gb is None:
        import psutil

        available_gb = psutil.virtual_memory().available / 2**30
    return max(1, min(cores or os.cpu_count() or 1, int(available_gb / RUN_MEMORY_GB)))


def launcher_overrides(launcher: str, sweep_dir: Path, jobs: int, job_name: str) -> list[str]:
    """Hydra-level overrides selecting the launcher, where jobs write and how they log."""
    overrides = [f"hydra.sweep.dir={sweep_dir.as_posix()}", f"hydra.job.name={job_name}",
                 "hydra/hydra_logging=study", "hydra/job_logging=study"]
    launcher = effective_launcher(launcher, jobs)
    overrides.append(f"hydra/launcher={launcher}")
    if launcher == "joblib":
        overrides.append(f"hydra.launcher.n_jobs={jobs}")
    return overrides


def launch(
    job_overrides: Sequence[Sequence[str]],
    task: TaskFunction,
    *,
    sweep_dir: Path,
    jobs: int = 1,
    job_name: str = "study",
    launcher: str = "basic",
    launcher_args: Sequence[str] = (),
) -> list[Any]:
    """Run ``task`` once per override list through Hydra's launcher plugin for ``launcher``;
    returns Hydra ``JobReturn`` objects in order.

    The launcher composes each job's config in full, creates its output folder
    ``<sweep_dir>/<job subdir>`` with ``.hydra/{config,overrides}.yaml`` and calls
    ``task(cfg)``; ``HydraConfig.get()`` inside the task gives the job's number and output
    folder. Exceptions the task lets through come back in the ``JobReturn``. Under ``local``,
    at most ``jobs`` run at once (``_at_most``).
    """
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.plugins import Plugins
    from hydra.experimental.callback import Callback
    from hydra.types import HydraContext, RunMode

    register()
    _STOP.clear()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3", job_name=job_name):
        loader = GlobalHydra.instance().config_loader()
        master = loader.load_configuration(
            config_name="train",
            overrides=[*launcher_overrides(launcher, sweep_dir, jobs, job_name), *launcher_args],
            run_mode=RunMode.MULTIRUN,
        )
        # no callbacks are configured: Hydra's public no-op Callback stands in for its dispatcher
        context = HydraContext(config_loader=loader, callbacks=Callback())
        plugin = Plugins.instance().instantiate_launcher(hydra_context=context, task_function=task, config=master)
        sweep_dir.mkdir(parents=True, exist_ok=True)  # launcher.log's folder
        if effective_launcher(launcher, jobs) == "local" and len(job_overrides) > jobs:
            return _at_most(jobs, plugin.launch, [list(o) for o in job_overrides])
        return list(plugin.launch([list(o) for o in job_overrides], initial_job_idx=0))


def _at_most(jobs: int, launch_one: Callable[..., Sequence[Any]], job_overrides: list[list[str]]) -> list[Any]:
    """Launch every job by itself (``launch_one([overrides], initial_job_idx=i)``, a job array
    of one, which returns when the job has ended), from ``jobs`` threads: at most ``jobs`` run at
    once, the next starting as one ends. Returns in order; if a launch raised (a job died without
    returning), the first error is raised once every job has ended, as the array's launch would.
    After ``stop_launching`` no further job starts."""
    returns: list[Any] = [None] * len(job_overrides)
    errors: list[BaseException] = []
    queue = iter(range(len(job_overrides)))
    lock = threading.Lock()

    def work() -> None:
        while True:
            with lock:
                i = None if _STOP.is_set() else next(queue, None)
            if i is None:
                return
            try:
                returns[i] = launch_one([job_overrides[i]], initial_job_idx=i)[0]
            except Exception as exc:
                errors.append(exc)

    # daemon threads: a stop (Ctrl-C, SIGTERM, SIGHUP) ends this process at once; stop_launching keeps
    # them from starting another job meanwhile
    threads = [threading.Thread(target=work, name=f"local-slot-{k}", daemon=True) for k in range(jobs)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    return returns


def default_jobs(study: str, profile: str, launcher: str = "basic") -> int:
    """Parallel runs when ``--jobs`` is not given: the profile's ``jobs`` (the quick profiles
    say 2: runs spend part of their time single-threaded - evaluation, diagnostics, logging),
    at most one per core; under ``--launcher local`` one per core, as many as fit in memory
    (``run.launchers.local_slots``)."""
    from harness.spec.study_files import load_study

    if launcher == "local":
        return local_slots()
    return max(1, min(load_study(study).profile(profile).jobs, os.cpu_count() or 1))
