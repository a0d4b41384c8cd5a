"""``ftgspp train [overrides]``: compose ``conf/train.yaml`` with Hydra and train one run.

Outputs go to the Hydra run directory (``outputs/<date>/<time>/`` unless
``hydra.run.dir=...``): the resolved config, checkpoints, ``metrics.json`` and eval renders.
The final metrics are printed as one JSON line on stdout.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from omegaconf import DictConfig

from ftgspp.errors import InputError
from ftgspp.tracker import RunResult
from harness.run.training import run_training
from harness.spec.schema import CONF_DIR, compose, register, to_train_config


def check_overrides(overrides: list[str]) -> None:
    """Compose once outside the app so a bad key or value is one clear line (exit 2)."""
    try:
        compose(overrides)
    except Exception as exc:  # Hydra/OmegaConf raise several types; all mean bad overrides
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError("override", first) from None


def main(overrides: list[str]) -> int:
    """Entry point used by ``ftgspp train``."""
    import hydra
    from hydra.core.hydra_config import HydraConfig

    check_overrides(overrides)
    register()
    result: dict[str, RunResult] = {}
    errors: list[InputError] = []

    @hydra.main(config_path=str(CONF_DIR), config_name="train", version_base="1.3")
    def _app(dcfg: DictConfig) -> None:
        out_dir = Path(HydraConfig.get().runtime.output_dir)
        try:
            result["run"] = run_training(to_train_config(dcfg), out_dir)
        except InputError as err:  # Hydra would print it with a traceback; we print one line
            errors.append(err)

    argv = sys.argv
    sys.argv = [argv[0], *overrides]
    try:
        _app()
    finally:
        sys.argv = argv
    if errors:
        raise errors[0]
    run = result["run"]
    print(json.dumps({"status": run.status, "failure": run.failure, "out_dir": str(run.out_dir), **run.metrics}))
    return 0 if run.status == "FINISHED" else 1
