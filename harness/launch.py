"""Launch a list of jobs through Hydra's launcher plugins.

Each job is a list of override strings for ``conf/train.yaml``. Hydra's plugin machinery
instantiates the launcher named by ``hydra/launcher`` (``harness.launchers``): the basic
launcher (in-process, one job after another) by default, the joblib launcher (``loky``
worker processes) for ``jobs > 1``, submitit's local or SLURM executor. The launcher
composes each job's config in full, creates its output folder
``<sweep_dir>/<job subdir>`` with ``.hydra/{config,overrides}.yaml`` and calls
``task(cfg)``; ``hydra.core.hydra_config.HydraConfig.get()`` inside the task gives the
job's number and output folder. Exceptions the task lets through come back in the
``JobReturn``; they are re-raised here only if the caller asks.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

from omegaconf import DictConfig

from harness.launchers import launcher_overrides
from harness.schema import CONF_DIR, register

TaskFunction = Callable[[DictConfig], Any]


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
    """Run ``task`` once per override list; returns Hydra ``JobReturn`` objects in order."""
    from hydra import initialize_config_dir
    from hydra._internal.callbacks import Callbacks
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.plugins import Plugins
    from hydra.types import HydraContext, RunMode

    register()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3", job_name=job_name):
        loader = GlobalHydra.instance().config_loader()
        master = loader.load_configuration(
            config_name="train",
            overrides=[*launcher_overrides(launcher, sweep_dir, jobs, job_name), *launcher_args],
            run_mode=RunMode.MULTIRUN,
        )
        context = HydraContext(config_loader=loader, callbacks=Callbacks(master))
        launcher = Plugins.instance().instantiate_launcher(hydra_context=context, task_function=task, config=master)
        return list(launcher.launch([list(o) for o in job_overrides], initial_job_idx=0))
