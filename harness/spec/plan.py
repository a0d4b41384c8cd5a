"""Compose every run of a study up front: validation, params and config hashes.

Each ``RunSpec``'s overrides are composed onto ``conf/train.yaml`` and the typed schema,
then resolved. A misspelt key, a wrong type, malformed override syntax or an unset
environment variable becomes one ``InputError`` naming the run, before anything is
written to the tracking store.

Hydra composition costs about half a second, and a study has hundreds of runs that
differ only in a few values. So, exactly as Hydra itself does, the defaults list is
composed once per distinct set of config-group overrides (``profile=quick``,
``data=dynerf``) and the value overrides (``model.gate=true``, ``seed=3``) are then
applied in order: parsed with Hydra's override grammar, set with ``OmegaConf.update``. The
launcher composes each job again in full; ``tests/harness`` checks that both give the same
config.
"""

from __future__ import annotations

from dataclasses import dataclass

from omegaconf import DictConfig

from ftgspp.config import TrainConfig
from ftgspp.errors import InputError
from harness.spec.confighash import config_hash, flatten_config
from harness.spec.runs import RunSpec
from harness.spec.schema import CONF_DIR, register, to_train_config
from harness.spec.synth import validate_synth

RunKey = tuple[str, str, int, str]  # variant, scene, seed, config_hash: how a run is found again


@dataclass(frozen=True)
class PlannedRun:
    """A run whose configuration composed and resolved."""

    spec: RunSpec
    params: dict[str, str]  # flattened resolved config
    config_hash: str

    @property
    def key(self) -> RunKey:
        """(variant, scene, seed, config_hash): the run's identity in the tracking store."""
        return (self.spec.variant, self.spec.scene.name, self.spec.seed, self.config_hash)

    @property
    def instance_of(self) -> str:
        """The scene as the study file writes it, whose instance this run's scene is (``spec.instances``)."""
        return self.spec.scene.base

    @property
    def instance(self) -> int:
        """Which instance of ``instance_of`` (0: the scene as written). Not a tag: read from the study."""
        return self.spec.scene.instance

    @property
    def tags(self) -> dict[str, str]:
        s = self.spec
        return {
            "study": s.study,
            "profile": s.profile,
            "variant": s.variant,
            "scene": s.scene.name,
            "seed": str(s.seed),
            "config_hash": self.config_hash,
        }


def error_line(exc: BaseException) -> str:
    """One line from a Hydra/OmegaConf exception, with its cause when that says more."""
    def first(e: BaseException) -> str:
        text = str(e).strip()
        return text.splitlines()[0] if text else type(e).__name__

    line = first(exc)
    if exc.__cause__ is not None and first(exc.__cause__) not in line:
        line = f"{line}: {first(exc.__cause__)}"
    return line


def resolve(dcfg: DictConfig, where: str) -> TrainConfig:
    """Typed config from a composed one; resolution errors become an InputError."""
    try:
        return to_train_config(dcfg)
    except InputError:
        raise
    except Exception as exc:  # OmegaConf raises several types for bad values / missing env
        raise InputError(where, error_line(exc)) from None


def _is_group(key: str) -> bool:
    return key.startswith("hydra") or (CONF_DIR / key).is_dir()


class Composer:
    """Composes override lists onto ``train.yaml`` inside one Hydra context, with caching.

    Config-group overrides go through ``hydra.compose`` once per distinct set; plain value
    overrides (``key=value``) are parsed by Hydra's override grammar and applied with
    ``OmegaConf.update``, as Hydra does. Anything else (``+key``, ``++key``, ``~key``)
    composes the whole list with ``hydra.compose``.
    """

    def __init__(self) -> None:
        from hydra.core.override_parser.overrides_parser import OverridesParser

        self._parser = OverridesParser.create()
        self._base: dict[tuple[str, ...], DictConfig] = {}

    def compose(self, overrides: list[str]) -> DictConfig:
        """Like ``hydra.compose(config_name='train', overrides=...)``; raises Hydra errors."""
        from hydra import compose
        from omegaconf import OmegaConf

        parsed = []
        for text in overrides:
            try:
                parsed.extend(self._parser.parse_overrides([text]))
            except Exception as exc:  # OverrideParseException: say which override
                raise ValueError(f"malformed override '{text}' ({error_line(exc)})") from None
        groups = tuple(o.input_line for o in parsed if _is_group(o.key_or_group))
        values = [o for o in parsed if not _is_group(o.key_or_group)]
        if any(o.is_delete() or o.is_add() or o.is_force_add() or o.package is not None for o in values):
            return compose(config_name="train", overrides=list(overrides))
        if groups not in self._base:
            self._base[groups] = compose(config_name="train", overrides=list(groups))
        cfg = self._base[groups].copy()
        for o in values:
            try:
                OmegaConf.update(cfg, o.key_or_group, o.value(), merge=True)
            except Exception as exc:  # unknown key or wrong type: say which override
                raise ValueError(f"could not override '{o.key_or_group}' ({error_line(exc)})") from None
        return cfg


def plan_runs(specs: list[RunSpec]) -> list[PlannedRun]:
    """Compose, resolve and hash every run; the first bad one raises ``InputError``."""
    from hydra import initialize_config_dir

    register()
    for scene in {s.scene.name: s.scene for s in specs}.values():
        validate_synth(scene)
    planned = []
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        composer = Composer()
        for spec in specs:
            where = f"{spec.study} variant '{spec.variant}', scene '{spec.scene.name}'"
            try:
                dcfg = composer.compose(list(spec.overrides))
            except Exception as exc:  # Hydra/OmegaConf: unknown key, bad value, bad syntax
                raise InputError(where, error_line(exc)) from None
            cfg = resolve(dcfg, where)
            params = flatten_config(cfg)
            planned.append(PlannedRun(spec, params, config_hash(params, spec.scene.synth)))
    return planned
