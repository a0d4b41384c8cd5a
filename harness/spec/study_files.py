"""Read ``studies/<name>.yaml`` onto the schema (``spec.study_schema``) and check it.

``load_study(name)`` reads the file in three steps; every problem is one ``InputError`` naming
the file and the key (``studies/<name>.yaml: profiles.quick.scenes[0].seeds``), which ``study run``
prints as one line before exiting 2:

1. YAML; a profile's ``scenes: <set>`` is replaced by that list of ``studies/_scene_sets.yaml``;
2. ``spec.structured.read``: keys, enum values (``TableLayout``, ``Comparison``, ...), types and
   mandatory keys against the schema, built into its frozen dataclasses;
3. ``_resolve``, the one pass over what types cannot say: names that must refer to variants,
   scenes, metrics and ladders, and what is derived (a rung's override or generator argument
   from the profile's ``ladders:``, so a rung's value is written once; synthetic-scene defaults,
   folders and instances (``spec.instances``); each profile's variants and baseline; whitespace-normalised text).
   The ``smoke`` profile is derived from ``quick`` when a study does not define one:
   ``profile=smoke`` (at full resolution), one seed and tiny synthetic scenes (64x48 pixels,
   6 frames, 5 cameras).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import re
from pathlib import Path
from typing import Any

import yaml

from ftgspp.errors import InputError
from harness.spec import instances, paper_register, structured
from harness.spec.metrics import claimable, sesoi
from harness.spec.paper_register import Register
from harness.spec.study_schema import (
    EXPECTATIONS,
    SYNTH_ROOT,
    ClaimSpec,
    Comparison,
    Expectation,
    Ladder,
    PlanSpec,
    ProfileSpec,
    StudyScene,
    StudySpec,
    VarianceSpec,
)

REPO_STUDIES = Path(__file__).resolve().parents[2] / "studies"  # the project's own study files
STUDIES_DIR = Path(os.environ.get("FTGSPP_STUDIES", REPO_STUDIES))
NAMED_FILE: Path | None = None  # the study file a command named by its path (``use_study_file``)
SCENE_SETS_FILE = "_scene_sets.yaml"
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")
TINY_SYNTH = {"width": 64, "height": 48, "n_frames": 6, "n_cameras": 5}
# the smoke scenes are generated at 64x48 already: train them at full resolution
SMOKE_OVERRIDES = ("profile=smoke", "data.downsample=1")


def list_studies(studies_dir: Path | None = None) -> list[str]:
    """Names of the study files (``_*.yaml`` files are shared data, not studies)."""
    root = Path(studies_dir or STUDIES_DIR)
    return sorted(p.stem for p in root.glob("*.yaml") if not p.name.startswith("_"))


def use_study_file(name: str) -> str:
    """The study a command names: a plain name (``secret5``) is returned as it is; a path to a study
    file (``path/to/mine.yaml``, anywhere) makes its folder this process's studies folder (a folder
    of one's own studies, with its own ``_scene_sets.yaml`` and ``_paper.yaml`` if it has them; the
    project's register of the paper does not apply there) and returns the file's stem. One
    ``InputError`` when the file does not exist."""
    global STUDIES_DIR, NAMED_FILE
    if not name.endswith((".yaml", ".yml")) and "/" not in name:
        return name
    path = Path(name).expanduser()
    if path.suffix != ".yaml":
        raise InputError(f"study file {name}", "a study file's name ends in .yaml")
    if not path.is_file():
        raise InputError(f"study file {name}", "no such file")
    STUDIES_DIR, NAMED_FILE = path.parent.resolve(), path
    return path.stem


def load_register(studies_dir: Path | None = None) -> Register:
    """The paper register (``studies/_paper.yaml``, ``spec.paper_register``), checked against
    every study file; one ``InputError`` at the first problem."""
    root = Path(studies_dir or STUDIES_DIR)
    if not (root / paper_register.REGISTER_FILE).is_file():  # a folder of one's own studies: no paper register
        return Register()
    register = paper_register.load_register(root)
    studies = {name: load_study(name, root) for name in list_studies(root)}
    paper_register.check_register(register, studies, str(root / paper_register.REGISTER_FILE))
    return register


def load_study(name: str, studies_dir: Path | None = None) -> StudySpec:
    """Parse and validate ``studies/<name>.yaml``; unknown names raise InputError."""
    root = Path(studies_dir or STUDIES_DIR)
    path = root / f"{name}.yaml"
    if name.startswith("_") or not NAME_PATTERN.match(name) or not path.is_file():
        known = ", ".join(list_studies(root)) or "none"
        raise InputError(f"study '{name}'", f"unknown study (known: {known})")
    sets = root / SCENE_SETS_FILE
    return _load_study(path, sets, _stamp(path), _stamp(sets))


def _stamp(path: Path) -> tuple[int, int] | None:
    """A file's modification time (ns) and size: what says a parsed copy of it is still current."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return None
    return st.st_mtime_ns, st.st_size


@functools.lru_cache(maxsize=128)
def _load_study(path: Path, sets: Path, path_stamp: object, sets_stamp: object) -> StudySpec:
    """``path`` parsed once per version of it and of the scene sets (``study index`` loads every
    study several times: a parse composes OmegaConf structures, a quarter of a second each).
    The spec is frozen; an error is raised again on every call (it is not cached)."""
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(path, f"not valid YAML ({str(exc).splitlines()[0]})") from None
    return parse_study(raw, path, (yaml.safe_load(sets.read_text()) or {}) if sets_stamp is not None else {})


def parse_study(raw: Any, path: Path, sets: dict[str, Any] | None = None) -> StudySpec:
    """Validate a loaded study file and build its spec (overrides are checked by composing)."""
    where = str(path)
    if not isinstance(raw, dict):
        raise InputError(where, "a study file must be a mapping")
    return _resolve(structured.read(_with_scene_sets(raw, sets or {}, where), StudySpec, where), path)


def require(cond: bool, where: str, problem: str) -> None:
    """Raise ``InputError(where, problem)`` unless ``cond``."""
    if not cond:
        raise InputError(where, problem)


# --- step 1: shared scene lists -----------------------------------------------------------


def _with_scene_sets(raw: dict[str, Any], sets: dict[str, Any], where: str) -> dict[str, Any]:
    """``raw`` with every profile's ``scenes: <set name>`` replaced by that set's list."""
    if not isinstance(raw.get("profiles"), dict):
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


# --- step 3: cross-references and derived values -------------------------------------------------


def _resolve(f: StudySpec, path: Path) -> StudySpec:
    """Check what types cannot say and derive the rest (module docstring)."""
    where = str(path)
    require(f.name == path.stem, where, f"name '{f.name}' must match the file name")
    variants = _variants(f.variants, f"{where}: variants")
    # a study needs only the profiles it uses (a method of one's own may have only a quick profile)
    require(bool(f.profiles), f"{where}: profiles", "needs at least one profile (quick, paper or smoke)")
    profiles = {str(name): _profile(str(name), p, f"{where}: profiles.{name}", variants)
                for name, p in f.profiles.items()}
    if "smoke" not in profiles and "quick" in profiles:
        profiles["smoke"] = _smoke_from_quick(profiles["quick"], f.name)
    for name, p in profiles.items():
        if not p.baseline:
            profiles[name] = p = dataclasses.replace(p, baseline=f.baseline)
        require(p.baseline in p.variants, f"{where}: baseline", f"'{p.baseline}' is not a variant of {p.name}")
    all_variants = {v for p in profiles.values() for v in p.variants}
    all_scenes = {sc.base for p in profiles.values() for sc in p.scenes}  # a claim names a scene as written
    claims = instances.check_claims(_claims(f.claims, f"{where}: claims", all_variants, all_scenes), profiles, where)
    return dataclasses.replace(
        f, question=" ".join(f.question.split()), notes=" ".join(f.notes.split()), path=path, profiles=profiles,
        variants=variants, claims=claims, variance=_variance(f.variance, f"{where}: variance_components", all_variants))


def _name(value: str, where: str, what: str) -> None:
    require(bool(NAME_PATTERN.match(value)), where, f"bad {what} name '{value}'")


def _variants(raw: dict[str, tuple[str, ...]], where: str) -> dict[str, tuple[str, ...]]:
    require(bool(raw), where, "must map variant names to override lists")
    for name in raw:
        _name(name, f"{where}.{name}", "variant")
    return raw


def _profile(name: str, p: ProfileSpec, where: str, variants: dict[str, tuple[str, ...]]) -> ProfileSpec:
    require(bool(p.scenes), f"{where}.scenes", "must be a non-empty list")
    for lname, lad in p.ladders.items():
        require(bool(lad.override) != bool(lad.synth), f"{where}.ladders.{lname}",
                "names either an override or a synth argument")
    for s in p.scenes:
        for lname, _ in s.rungs:
            require(lname in p.ladders or not p.ladders, f"{where}.scenes.{s.name}.rungs",
                    f"unknown ladder '{lname}' (profile ladders: {', '.join(p.ladders)})")
    scenes = tuple(x for i, s in enumerate(p.scenes) for x in _scene(s, f"{where}.scenes[{i}]", name, p.ladders))
    names = [s.name for s in scenes]
    require(len(set(names)) == len(names), f"{where}.scenes", "scene names must be unique")
    require(p.seeds >= 1, f"{where}.seeds", "must be a positive integer")
    require(p.jobs >= 1, f"{where}.jobs", "must be a positive integer")
    _plan(p.sequential, f"{where}.sequential")
    prof_variants = _variants(p.variants, f"{where}.variants") if p.variants is not None else variants
    for s in scenes:
        for v in s.variants:
            require(v in prof_variants, f"{where}.scenes.{s.name}.variants",
                    f"unknown variant '{v}' (have {', '.join(prof_variants)})")
    return dataclasses.replace(p, name=name, scenes=scenes, variants=prof_variants)


def _scene(s: StudyScene, where: str, profile: str, ladders: dict[str, Ladder]) -> list[StudyScene]:
    _name(s.name, where, "scene")
    require(s.seeds is None or s.seeds >= 1, f"{where}.seeds", "must be a positive integer")
    rung_overrides, rung_synth = _rung_settings(s, ladders, where)
    overrides = (*s.overrides, *rung_overrides)
    synth = None if s.synth is None and not rung_synth else {**(s.synth or {}), **rung_synth}
    require(synth is not None or bool(overrides), where, "needs synth args or data overrides")
    synth_dir = ""
    if synth is not None:
        synth = {"preset": "studio", "seed": 0, "layout": "dynerf", **synth}
        suffix = "-smoke" if profile == "smoke" else ""
        synth_dir = (SYNTH_ROOT / f"{s.name}{suffix}").as_posix()
    return instances.expand(dataclasses.replace(s, synth=synth, overrides=overrides, synth_dir=synth_dir), where)


def _rung_settings(s: StudyScene, ladders: dict[str, Ladder], where: str) -> tuple[tuple[str, ...], dict[str, Any]]:
    """The overrides and generator arguments the scene's rungs set (``Ladder``)."""
    overrides: list[str] = []
    synth: dict[str, Any] = {}
    for ladder, value in s.rungs:
        lad = ladders.get(ladder)
        if lad is None or lad.base is not None and value == lad.base:
            continue
        if lad.override:
            key = lad.override
            require(not any(o.split("=", 1)[0].lstrip("+~") == key for o in s.overrides), f"{where}.overrides",
                    f"'{key}' is set by the rung {ladder}: {value:g} (profile ladders), not here")
            overrides.append(f"{key}={_override_value(key, value * lad.times, f'{where}.rungs.{ladder}')}")
        else:
            require(lad.synth not in (s.synth or {}), f"{where}.synth",
                    f"'{lad.synth}' is set by the rung {ladder}: {value:g} (profile ladders), not here")
            synth[lad.synth] = _synth_value(lad.synth, value * lad.times, f"{where}.rungs.{ladder}")
    return tuple(overrides), synth


def _override_value(key: str, value: float, where: str) -> str:
    """``value`` written for the ``TrainConfig`` field ``key`` (dotted): a whole number for an int
    field (``init.keyframe_stride=5``), else the float's repr (``lr.scale=24.0``)."""
    import typing

    from ftgspp.config import TrainConfig

    kind: Any = TrainConfig
    for part in key.split("."):
        hints = typing.get_type_hints(kind) if dataclasses.is_dataclass(kind) else {}
        kind = hints.get(part)
    if kind is not None and int in typing.get_args(kind) + (kind,) and float not in typing.get_args(kind) + (kind,):
        require(float(value).is_integer(), where, f"{key} needs a whole number, not {value:g}")
        return str(int(value))
    return repr(value)


def _synth_value(field: str, value: float, where: str) -> int | float:
    """``value`` as the synthetic generator's ``field`` type (``SynthConfig``: int or float)."""
    from ftgspp.data.synthetic.presets import SynthConfig

    types = {f.name: f.type for f in dataclasses.fields(SynthConfig)}
    require(field in types, where, f"'{field}' is not a synthetic scene argument")
    if "int" in str(types[field]):
        require(float(value).is_integer(), where, f"{field} needs a whole number, not {value:g}")
        return int(value)
    return float(value)


def _smoke_from_quick(quick: ProfileSpec, study: str) -> ProfileSpec:
    scenes = []
    for s in quick.scenes:
        synth = dict(s.synth or {"preset": "studio", "seed": 0, "layout": "dynerf"})
        tiny = dict(TINY_SYNTH)
        if int(synth.get("n_cameras", 99)) < tiny["n_cameras"]:
            tiny["n_cameras"] = int(synth["n_cameras"])
        synth.update(tiny)
        keep = tuple(o for o in s.overrides if not o.startswith("data.path="))
        scenes.append(StudyScene(s.name, synth, keep, s.label, (SYNTH_ROOT / f"{s.name}-smoke").as_posix(),
                                 None, s.variants, s.rungs, s.instances, s.instance_of, s.instance))
    return ProfileSpec(
        name="smoke",
        seeds=1,  # the quick profile's own overrides (e.g. determinism=portable) carry over
        overrides=(*SMOKE_OVERRIDES, *(o for o in quick.overrides if not o.startswith("profile="))),
        scenes=tuple(scenes),
        variants=quick.variants,
        expected_runtime="seconds per run (tests only)",
        command=f"study run {study} --profile smoke",
        baseline=quick.baseline,
        machine="",  # no estimate (run_seconds 0)
        sequential=quick.sequential,
    )


def _plan(plan: PlanSpec | None, where: str) -> None:
    """Check a sequential plan's numbers (a profile's ``sequential:`` or a claim's ``plan:``)."""
    for k, least in (("first", 2), ("per_round", 1), ("rounds", 1), ("cap_runs", 2)):
        value = getattr(plan, k, None)
        require(value is None or value >= least, f"{where}.{k}", f"must be at least {least}")
    for k in ("cap_cpu_hours", "study_cap_cpu_hours"):
        value = getattr(plan, k, None)
        require(value is None or value > 0, f"{where}.{k}", "must be positive")


def _variance(v: VarianceSpec | None, where: str, variants: set[str]) -> VarianceSpec | None:
    """Check ``variance_components:`` (variants: those of any profile)."""
    if v is None:
        return None
    require(len(v.hardware) >= 2, f"{where}.hardware", "needs at least two dispatch variants")
    for key, name in [("optimisation", v.optimisation), ("initialisation", v.initialisation)] + \
            [("hardware", h) for h in v.hardware]:
        require(name in variants, f"{where}.{key}", f"unknown variant '{name}' (have {', '.join(sorted(variants))})")
    return v


def _claims(claims: tuple[ClaimSpec, ...], where: str, variants: set[str], scenes: set[str]
            ) -> tuple[ClaimSpec, ...]:
    """Check a study's ``claims:`` (variants and scenes: those of any profile) and fill in each
    claim's smallest effect of interest from the metric registry."""
    out: list[ClaimSpec] = []
    for c in claims:
        at = f"{where}.{c.id}"
        require(bool(NAME_PATTERN.match(c.id)) and c.id not in {o.id for o in out}, at,
                "claim ids must be unique names")
        require(c.expect in EXPECTATIONS[c.test], f"{at}.expect",
                f"'{c.expect}' is not an expectation of a {c.test} test (use {', '.join(EXPECTATIONS[c.test])})")
        for key, metric in (("metric", c.metric), ("versus", c.versus)):
            require(metric in claimable() or (key == "versus" and not metric), f"{at}.{key}",
                    f"unknown metric '{metric}' (use {', '.join(claimable())})")
        for v in c.arms():
            require(v in variants, at, f"unknown variant '{v}' (have {', '.join(sorted(variants))})")
        require(not c.among or (c.test in (Comparison.decoupled, Comparison.dissociated) and len(c.among) >= 2),
                f"{at}.among", "only a decoupled or dissociated claim searches 'among' variants (two or more)")
        # a claim's scope is fixed when it is registered: its scenes and its arms, named in the claim,
        # so adding a scene or a variant to the study later cannot widen it (tests/harness/test_claim_scopes.py)
        require(bool(c.scenes), f"{at}.scenes", "name the claim's scenes (scenes: [...]): a claim's scope is fixed"
                " when it is registered, so a scene added to the study later cannot join it")
        for sc in c.scenes:  # a withdrawn claim may name a scene the study no longer runs
            require(sc in scenes or bool(c.withdrawn), f"{at}.scenes", f"unknown scene '{sc}' (have {', '.join(sorted(scenes))})")
        if c.test in (Comparison.decoupled, Comparison.dissociated):
            require(bool(c.versus), at, f"a {c.test} claim needs 'versus' (the metric that differs)")
            require(len(c.among) >= 2, f"{at}.among", f"name the variants a {c.test} claim searches (among: [...],"
                    " two or more): its arms are fixed when it is registered")
        elif c.test == Comparison.contrast:
            require(bool(c.contrasts) and all(isinstance(k, (int, float)) for w in c.contrasts for _, k in w)
                    and all(abs(sum(k for _, k in w)) < 1e-9 for w in c.contrasts), f"{at}.contrasts",
                    "needs maps of variant -> number weights that each sum to 0")
        elif c.test == Comparison.interaction and c.pairs:
            require(len(c.pairs) == len(c.scenes) and all(len(p) == 2 for p in c.pairs), f"{at}.pairs",
                    "needs one [a, b] per scene, in the order of scenes")
            require(not c.a and not c.b, at, "an interaction with pairs names no a or b")
        else:
            require(bool(c.a), f"{at}.a", f"a {c.test} claim needs variant 'a'")
            require(bool(c.b) or c.test in (Comparison.mean, Comparison.spread), f"{at}.b",
                    f"a {c.test} claim needs variant 'b'")
        if c.test == Comparison.interaction:
            require(len(c.scenes) == 2, f"{at}.scenes", "an interaction needs exactly two scenes")
        require(c.plan is None or c.test == Comparison.mean, f"{at}.plan", "only a mean claim runs until decided")
        _plan(c.plan, f"{at}.plan")
        if c.expect == Expectation.equivalent:
            require(c.test in (Comparison.mean, Comparison.interaction, Comparison.variance), f"{at}.expect",
                    "an equivalence claim compares two variants' means, spreads or an interaction")
        for i, r in enumerate(c.requires):
            require(r.metric in claimable(), f"{at}.requires[{i}].metric", f"unknown metric '{r.metric}'")
            require((r.min is None) != (not r.above), f"{at}.requires[{i}]", "give either min or above")
            if r.above:
                require(r.above in claimable() or _is_number(r.above), f"{at}.requires[{i}].above",
                        f"'{r.above}' is neither a metric nor a number")
        try:
            value, scale = sesoi(c.metric, c.test)
        except ValueError as err:
            raise InputError(f"{at}.metric", f"{err}; a claim needs one (docs/sesoi.md)") from None
        out.append(dataclasses.replace(
            c, statement=" ".join(c.statement.split()), withdrawn=" ".join(c.withdrawn.split()),
            history=tuple(" ".join(h.split()) for h in c.history),
            sesoi=value, sesoi_source=f"docs/sesoi.md, {scale}",
            contrasts=tuple(tuple((v, float(k)) for v, k in w) for w in c.contrasts)))
    return tuple(out)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
