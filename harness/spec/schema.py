"""Registers the dataclass schema of ``ftgspp.config`` with Hydra's ConfigStore.

YAML files in ``conf/`` hold values only; composing them onto ``TrainConfig`` makes a
misspelt key or a wrongly typed value fail at composition time.
"""

from __future__ import annotations

import os
from pathlib import Path

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf

from ftgspp.config import TrainConfig

CONF_DIR = Path(os.environ.get("FTGSPP_CONF", Path(__file__).resolve().parents[2] / "conf"))


def register() -> None:
    """Store the schema under the name ``train_schema`` (idempotent)."""
    ConfigStore.instance().store(name="train_schema", node=TrainConfig)


def to_train_config(cfg: DictConfig) -> TrainConfig:
    """Convert a composed config (hydra keys dropped) to the typed dataclass."""
    cfg = OmegaConf.masked_copy(cfg, [k for k in cfg.keys() if k != "hydra"]) if "hydra" in cfg else cfg
    obj = OmegaConf.to_object(cfg)
    assert isinstance(obj, TrainConfig)
    return obj


def compose(overrides: list[str] | None = None, config_name: str = "train") -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with ``overrides`` outside of a Hydra app."""
    from hydra import compose as hydra_compose, initialize_config_dir

    register()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name=config_name, overrides=list(overrides or []))
