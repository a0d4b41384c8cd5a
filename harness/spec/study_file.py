"""The schema of ``studies/<name>.yaml``: dataclasses that OmegaConf fills and type-checks.

``read(raw, where)`` merges a loaded YAML mapping onto ``StudyFile``: an unknown key, a
missing mandatory one or a value of the wrong type becomes one ``InputError`` naming the
file and the key (``profiles.quick.scenes[0].seeds``). What the types cannot say (names
that must refer to variants or scenes, allowed values) ``spec.files`` checks next.

A profile's ``scenes`` may be the name of a shared list in ``studies/_scene_sets.yaml``;
it is replaced by that list before the merge (``scene_sets``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional

from ftgspp.errors import InputError

MISSING: Any = "???"  # OmegaConf's mandatory-value marker


@dataclass
class LadderFile:
    """What a rung value of one stability ladder sets: an override or a synthetic-scene argument.

    ``override: lr.scale, times: 2`` makes the rung ``{lr_scale: 3}`` the override
    ``lr.scale=6.0``; ``synth: n_cameras`` makes ``{cameras: 6}`` the generator argument
    ``n_cameras: 6``. A rung at ``base`` sets nothing (the profile's own value).
    """

    override: str = ""
    synth: str = ""
    times: float = 1.0
    base: Optional[float] = None


@dataclass
class SceneFile:
    """One scene (or difficulty cell) of a profile."""

    name: str = MISSING
    synth: Optional[Dict[str, Any]] = None
    overrides: List[str] = field(default_factory=list)
    label: str = ""
    seeds: Optional[int] = None
    variants: List[str] = field(default_factory=list)
    rungs: Dict[str, float] = field(default_factory=dict)


@dataclass
class ProfileFile:
    """How the study runs under one profile."""

    scenes: List[SceneFile] = MISSING
    seeds: int = 1
    jobs: int = 1
    overrides: List[str] = field(default_factory=list)
    variants: Optional[Dict[str, List[str]]] = None
    ladders: Dict[str, LadderFile] = field(default_factory=dict)
    run_seconds: float = 0.0  # wall seconds per run (one at a time) on ``machine``; 0 = unknown
    machine: str = "an idle 2-core CPU machine (EPYC-AVX2, BENCHMARKS.md)"
    expected_runtime: str = ""  # a note for people (GPU profiles); the estimate comes from run_seconds
    command: str = ""
    baseline: str = ""


@dataclass
class TableFile:
    layout: str = "variants_x_scenes"
    metrics: List[str] = field(default_factory=lambda: ["psnr"])
    unranked: List[str] = field(default_factory=list)  # variants shown but never marked best (e.g. controls)


@dataclass
class PaperRowFile:
    """The paper's numbers on one dataset (``spec.study.PaperRow``)."""

    dataset: str = MISSING
    a: Optional[float] = None
    b: Optional[float] = None
    a_std: Optional[float] = None
    b_std: Optional[float] = None
    n: Optional[int] = None
    run_sd: Optional[float] = None
    run_sd_n: Optional[int] = None
    scene: str = ""
    note: str = ""


@dataclass
class PaperFile:
    statement: str = MISSING
    source: str = MISSING
    rows: List[PaperRowFile] = field(default_factory=list)


@dataclass
class RequiresFile:
    metric: str = MISSING
    min: float = MISSING


@dataclass
class ClaimFile:
    """One claim as a test on the study's runs (``spec.study.ClaimSpec``)."""

    id: str = MISSING
    claim: str = MISSING
    metric: str = MISSING
    test: str = MISSING
    expect: str = MISSING
    sesoi: float = MISSING
    sesoi_source: str = MISSING
    group: str = "paper"
    a: str = ""
    b: str = ""
    scenes: List[str] = field(default_factory=list)
    pair: str = "seed"
    versus: str = ""
    paper: Optional[PaperFile] = None
    contrasts: List[Dict[str, Any]] = field(default_factory=list)  # variant -> weight (numbers: spec.files)
    requires: Optional[RequiresFile] = None
    needs: str = ""  # real data the claim needs (its scenes are in the paper profile only)


@dataclass
class VarianceFile:
    metric: str = MISSING
    optimisation: str = MISSING
    initialisation: str = MISSING
    hardware: List[str] = MISSING


@dataclass
class StudyFile:
    """A whole study file."""

    name: str = MISSING
    question: str = MISSING
    baseline: str = MISSING
    variants: Dict[str, List[str]] = MISSING
    profiles: Dict[str, ProfileFile] = MISSING
    base_seed: int = 0
    metrics: List[str] = field(default_factory=lambda: ["psnr"])
    table: TableFile = field(default_factory=TableFile)
    plots: List[str] = field(default_factory=list)
    diagnostics: List[str] = field(default_factory=list)
    notes: str = ""
    claims: List[ClaimFile] = field(default_factory=list)
    variance_components: Optional[VarianceFile] = None


def scene_sets(raw: Any, sets: dict[str, Any], where: str) -> Any:
    """``raw`` with every profile's ``scenes: <set name>`` replaced by that set's list."""
    if not isinstance(raw, dict) or not isinstance(raw.get("profiles"), dict):
        return raw
    profiles = {}
    for name, prof in raw["profiles"].items():
        if isinstance(prof, dict) and isinstance(prof.get("scenes"), str):
            if prof["scenes"] not in sets:
                raise InputError(f"{where}: profiles.{name}.scenes",
                                 f"unknown scene set '{prof['scenes']}' (_scene_sets.yaml)")
            prof = {**prof, "scenes": sets[prof["scenes"]]}
        profiles[name] = prof
    return {**raw, "profiles": profiles}


def _unknown_key(raw: Any, cls: type, path: str = "") -> tuple[str, str, list[str]] | None:
    """The first key of ``raw`` that the dataclass ``cls`` (or a nested one) lacks:
    (path of the mapping, key, allowed keys)."""
    import dataclasses
    import typing

    if not isinstance(raw, dict):
        return None
    hints = typing.get_type_hints(cls)
    for key, value in raw.items():
        if key not in hints:
            return path, str(key), [f.name for f in dataclasses.fields(cls)]
        inner = [a for a in typing.get_args(hints[key]) if dataclasses.is_dataclass(a)] or [hints[key]]
        sub, origin = inner[-1], typing.get_origin(hints[key])
        if not dataclasses.is_dataclass(sub):
            continue
        if origin in (list, List) and isinstance(value, list):
            for i, item in enumerate(value):
                if found := _unknown_key(item, sub, f"{path}{key}[{i}]."):
                    return found
        elif origin in (dict, Dict) and isinstance(value, dict):
            for name, item in value.items():
                if found := _unknown_key(item, sub, f"{path}{key}.{name}."):
                    return found
        elif origin is None and (found := _unknown_key(value, sub, f"{path}{key}.")):
            return found
    return None


def _problem(exc: Exception) -> str:
    """One line from an OmegaConf error."""
    from omegaconf.errors import MissingMandatoryValue

    if isinstance(exc, MissingMandatoryValue):
        return f"missing key '{str(getattr(exc, 'full_key', '')).rsplit('.', 1)[-1]}'"
    text = str(exc).strip().splitlines()[0]
    return "must be a list" if "is not a ListConfig" in text else "must be a mapping" if "DictConfig" in text else text


def _escaped(value: Any) -> Any:
    """``value`` with every ``${`` escaped, so OmegaConf keeps interpolations as text."""
    if isinstance(value, str):
        return value.replace("${", "\\${")
    if isinstance(value, dict):
        return {k: _escaped(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_escaped(v) for v in value]
    return value


def read(raw: Any, where: str) -> StudyFile:
    """Type-check a loaded study file against ``StudyFile``; one-line ``InputError`` if it fails."""
    from omegaconf import OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    if not isinstance(raw, dict):
        raise InputError(where, "a study file must be a mapping")
    if unknown := _unknown_key(raw, StudyFile):
        at, key, allowed = unknown
        raise InputError(f"{where}: {at}{key}", f"unknown key(s) {key} (use {', '.join(allowed)})")
    try:
        # overrides keep their ${oc.env:...} text (escaped here): Hydra resolves them per run
        cfg = OmegaConf.merge(OmegaConf.structured(StudyFile), _escaped(raw))
        out = OmegaConf.to_object(cfg)
    except OmegaConfBaseException as exc:
        key = str(getattr(exc, "full_key", "") or "").strip()
        raise InputError(f"{where}: {key}" if key else where, _problem(exc)) from None
    assert isinstance(out, StudyFile)
    return out
