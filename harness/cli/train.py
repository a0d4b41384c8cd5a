"""``ftgspp train [overrides]``: compose ``conf/train.yaml`` with Hydra and train one run.

Hydra owns the command line (``hydra_app`` is an ordinary ``@hydra.main`` app; the ``ftgspp``
dispatcher hands it the arguments after ``train``), so its conventions work as documented:
``ftgspp train --help`` lists the config groups and every key with its default,
``ftgspp train --cfg job [overrides]`` prints the composed config, ``--info`` the search path.

Before Hydra creates the run folder the overrides are checked (``validate``): a misspelt key,
a wrong type, an unknown group option or a missing scene folder is one line naming the key,
the reason and the valid choices, exit status 2, and nothing is written. Outputs go to the
Hydra run directory (``outputs/<date>/<time>/`` unless ``hydra.run.dir=...``): the resolved
config, checkpoints, ``metrics.json`` and eval renders; the final metrics are printed as one
JSON line on stdout. A run whose scene turns out to be unreadable removes the folder Hydra
made for it.
"""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
from pathlib import Path

import hydra
from omegaconf import DictConfig

from ftgspp.config import TrainConfig
from ftgspp.errors import InputError
from harness.run.training import run_training
from harness.spec.schema import CONF_DIR, compose, register, to_train_config

HYDRA_FLAGS = ("--help", "-h", "--hydra-help", "--cfg", "-c", "--info", "--resolve", "--package", "-p",
               "--version", "--shell-completion", "-sc", "--multirun", "-m", "--config-path", "-cp",
               "--config-name", "-cn", "--config-dir", "-cd", "--experimental-rerun")


def _section_keys(key: str) -> str:
    """The keys of the config section ``key`` lives in (``model.bogus`` -> ModelConfig's fields)."""
    node: object = TrainConfig()
    for part in key.split(".")[:-1]:
        node = getattr(node, part, None)
    if node is None or not dataclasses.is_dataclass(node):
        return ""
    return ", ".join(f.name for f in dataclasses.fields(node))


def override_problem(exc: BaseException) -> str:
    """One line from a Hydra/OmegaConf composition error: the key, the reason, the choices."""
    text = str(exc).strip()
    missing = re.search(r"Could not find '([\w/]+)/([^']+)'.*?Available options in '[\w/]+':((?:\s*\t\S+)+)",
                        text, flags=re.S)
    if missing:
        group, value, options = missing.group(1), missing.group(2), missing.group(3).split()
        return f"{group}={value}: unknown {group} (choose from {', '.join(options)})"
    unknown = re.match(r"Could not override '([\w.]+)'", text)
    if unknown:
        key = unknown.group(1)
        keys = _section_keys(key)
        return f"{key}: unknown key" + (f" (this section has: {keys})" if keys else "")
    first = text.splitlines()[0] if text else type(exc).__name__
    cause = exc.__cause__
    if cause is not None and str(cause).strip():
        reason = str(cause).strip().splitlines()[0]
        key = re.search(r"full_key: ([\w.]+)", str(cause))
        return f"{key.group(1) + ': ' if key else ''}{reason}" if reason not in first else first
    return first


def validate(overrides: list[str]) -> TrainConfig:
    """Compose and type the config and check the scene folder, before anything is written."""
    try:
        cfg = to_train_config(compose(overrides))
    except InputError:
        raise
    except Exception as exc:  # Hydra/OmegaConf raise several types; all mean bad overrides
        raise InputError("override", override_problem(exc)) from None
    from ftgspp.trainer import check_config

    check_config(cfg)
    if not cfg.data.path:
        raise InputError("data.path", "no scene given (data.path=DIR; `ftgspp synth --out DIR` makes one)")
    if not Path(cfg.data.path).is_dir():
        raise InputError("data.path", f"{cfg.data.path}: no such folder")
    return cfg


_RESULT: dict[str, object] = {}  # what the Hydra app leaves for ``main`` (Hydra swallows return values)


@hydra.main(config_path=str(CONF_DIR), config_name="train", version_base="1.3")
def hydra_app(dcfg: DictConfig) -> None:
    """The Hydra app: train the composed config into Hydra's run folder."""
    from hydra.core.hydra_config import HydraConfig

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        _RESULT["run"] = run_training(to_train_config(dcfg), out_dir)
    except InputError as err:  # Hydra would print a traceback: ``main`` prints one line instead
        _RESULT["error"] = err
        if all(p.name in (".hydra", "train.log") for p in out_dir.iterdir()):
            shutil.rmtree(out_dir, ignore_errors=True)  # the scene could not be read: leave nothing behind


def main(args: list[str]) -> int:
    """``ftgspp train ARGS``; ``sys.argv`` must read ``[prog, *ARGS]`` (the dispatcher sets it)."""
    register()
    if not any(a.split("=", 1)[0] in HYDRA_FLAGS for a in args):
        validate([a for a in args if not a.startswith("hydra")])
    _RESULT.clear()
    hydra_app()
    if "error" in _RESULT:
        raise _RESULT["error"]  # type: ignore[misc]
    run = _RESULT.get("run")
    if run is None:  # --help, --cfg, --info: Hydra printed what was asked
        return 0
    print(json.dumps({"status": run.status, "failure": run.failure, "out_dir": str(run.out_dir), **run.metrics}))
    return 0 if run.status == "FINISHED" else 1
