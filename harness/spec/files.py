"""Read and validate ``studies/<name>.yaml`` into a ``StudySpec``.

``load_study(name)`` reads the file; ``spec.study_file.read`` checks its structure and types
against the dataclass schema, then ``parse_study`` checks what types cannot (names that must
refer to variants, scenes, metrics and ladders; allowed values) and builds the spec. Every
problem is one ``InputError`` naming the key (``study run`` prints it as one line and exits 2).
A rung of a stability ladder sets its override or generator argument from the profile's
``ladders:`` entry, so a rung's value is written once. A profile's ``scenes`` may name a shared
set in ``studies/_scene_sets.yaml``. The ``smoke`` profile is derived from ``quick`` when a
study does not define one: ``profile=smoke`` (at full resolution), one seed and tiny
synthetic scenes (64x48 pixels, 6 frames, 5 cameras).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import yaml

from ftgspp.errors import InputError
from harness.spec import study_file
from harness.spec.metrics import claimable
from harness.spec.study import (
    CLAIM_GROUPS,
    CLAIM_TESTS,
    NAME_PATTERN,
    PLOTS,
    PROFILES,
    SMOKE_OVERRIDES,
    SYNTH_ROOT,
    TABLE_LAYOUTS,
    TINY_SYNTH,
    ClaimSpec,
    PaperClaim,
    PaperRow,
    ProfileSpec,
    StudyScene,
    StudySpec,
    TableSpec,
    VarianceSpec,
)
from harness.spec.study_file import ClaimFile, LadderFile, PaperFile, ProfileFile, SceneFile, VarianceFile

STUDIES_DIR = Path(os.environ.get("FTGSPP_STUDIES", Path(__file__).resolve().parents[2] / "studies"))
SCENE_SETS_FILE = "_scene_sets.yaml"


def list_studies(studies_dir: Path | None = None) -> list[str]:
    """Names of the study files (``_*.yaml`` files are shared data, not studies)."""
    root = Path(studies_dir or STUDIES_DIR)
    return sorted(p.stem for p in root.glob("*.yaml") if not p.name.startswith("_"))


def load_study(name: str, studies_dir: Path | None = None) -> StudySpec:
    """Parse and validate ``studies/<name>.yaml``; unknown names raise InputError."""
    root = Path(studies_dir or STUDIES_DIR)
    path = root / f"{name}.yaml"
    if name.startswith("_") or not NAME_PATTERN.match(name) or not path.is_file():
        known = ", ".join(list_studies(root)) or "none"
        raise InputError(f"study '{name}'", f"unknown study (known: {known})")
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(path, f"not valid YAML ({str(exc).splitlines()[0]})") from None
    return parse_study(raw, path, _scene_sets(root))


def _scene_sets(root: Path) -> dict[str, Any]:
    path = root / SCENE_SETS_FILE
    return (yaml.safe_load(path.read_text()) or {}) if path.is_file() else {}


def require(cond: bool, where: str, problem: str) -> None:
    """Raise ``InputError(where, problem)`` unless ``cond``."""
    if not cond:
        raise InputError(where, problem)


def _name(value: str, where: str, what: str) -> None:
    require(bool(NAME_PATTERN.match(value)), where, f"bad {what} name '{value}'")


def _variants(raw: dict[str, list[str]], where: str) -> dict[str, tuple[str, ...]]:
    require(bool(raw), where, "must map variant names to override lists")
    for name in raw:
        _name(name, f"{where}.{name}", "variant")
    return {name: tuple(overrides) for name, overrides in raw.items()}


def _rung_settings(raw: SceneFile, ladders: dict[str, LadderFile], where: str
                   ) -> tuple[tuple[str, ...], dict[str, Any]]:
    """The overrides and generator arguments the scene's rungs set (``LadderFile``)."""
    overrides: list[str] = []
    synth: dict[str, Any] = {}
    for ladder, value in raw.rungs.items():
        lad = ladders.get(ladder)
        if lad is None or lad.base is not None and value == lad.base:
            continue
        if lad.override:
            key = lad.override
            require(not any(o.split("=", 1)[0].lstrip("+~") == key for o in raw.overrides), f"{where}.overrides",
                    f"'{key}' is set by the rung {ladder}: {value:g} (profile ladders), not here")
            overrides.append(f"{key}={value * lad.times!r}")
        else:
            require(lad.synth not in (raw.synth or {}), f"{where}.synth",
                    f"'{lad.synth}' is set by the rung {ladder}: {value:g} (profile ladders), not here")
            synth[lad.synth] = _synth_value(lad.synth, value * lad.times, f"{where}.rungs.{ladder}")
    return tuple(overrides), synth


def _synth_value(field: str, value: float, where: str) -> int | float:
    """``value`` as the synthetic generator's ``field`` type (``SynthConfig``: int or float)."""
    import dataclasses

    from ftgspp.data.synthetic.presets import SynthConfig

    types = {f.name: f.type for f in dataclasses.fields(SynthConfig)}
    require(field in types, where, f"'{field}' is not a synthetic scene argument")
    if "int" in str(types[field]):
        require(float(value).is_integer(), where, f"{field} needs a whole number, not {value:g}")
        return int(value)
    return float(value)


def _scene(raw: SceneFile, where: str, profile: str, ladders: dict[str, LadderFile]) -> StudyScene:
    _name(raw.name, where, "scene")
    require(raw.seeds is None or raw.seeds >= 1, f"{where}.seeds", "must be a positive integer")
    rung_overrides, rung_synth = _rung_settings(raw, ladders, where)
    overrides = (*raw.overrides, *rung_overrides)
    synth = None if raw.synth is None and not rung_synth else {**(raw.synth or {}), **rung_synth}
    require(synth is not None or bool(overrides), where, "needs synth args or data overrides")
    synth_dir = ""
    if synth is not None:
        synth = {"preset": "studio", "seed": 0, "layout": "dynerf", **synth}
        suffix = "-smoke" if profile == "smoke" else ""
        synth_dir = (SYNTH_ROOT / f"{raw.name}{suffix}").as_posix()
    rungs = tuple((k, float(v)) for k, v in raw.rungs.items())
    return StudyScene(raw.name, synth, overrides, raw.label, synth_dir, raw.seeds, tuple(raw.variants), rungs)


def _profile(name: str, raw: ProfileFile, where: str, variants: dict[str, tuple[str, ...]]) -> ProfileSpec:
    require(bool(raw.scenes), f"{where}.scenes", "must be a non-empty list")
    for lname, lad in raw.ladders.items():
        require(bool(lad.override) != bool(lad.synth), f"{where}.ladders.{lname}",
                "names either an override or a synth argument")
    for s in raw.scenes:
        for lname in s.rungs:
            require(lname in raw.ladders or not raw.ladders, f"{where}.scenes.{s.name}.rungs",
                    f"unknown ladder '{lname}' (profile ladders: {', '.join(raw.ladders)})")
    scenes = tuple(_scene(s, f"{where}.scenes[{i}]", name, raw.ladders) for i, s in enumerate(raw.scenes))
    names = [s.name for s in scenes]
    require(len(set(names)) == len(names), f"{where}.scenes", "scene names must be unique")
    require(raw.seeds >= 1, f"{where}.seeds", "must be a positive integer")
    require(raw.jobs >= 1, f"{where}.jobs", "must be a positive integer")
    prof_variants = _variants(raw.variants, f"{where}.variants") if raw.variants is not None else variants
    for s in scenes:
        for v in s.variants:
            require(v in prof_variants, f"{where}.scenes.{s.name}.variants",
                    f"unknown variant '{v}' (have {', '.join(prof_variants)})")
    return ProfileSpec(name=name, seeds=raw.seeds, overrides=tuple(raw.overrides), scenes=scenes,
                       variants=prof_variants, expected_runtime=raw.expected_runtime, command=raw.command,
                       baseline=raw.baseline, jobs=raw.jobs, run_seconds=raw.run_seconds, machine=raw.machine)


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
                                 None, s.variants, s.rungs))
    return ProfileSpec(
        name="smoke",
        seeds=1,  # the quick profile's own overrides (e.g. determinism=portable) carry over
        overrides=(*SMOKE_OVERRIDES, *(o for o in quick.overrides if not o.startswith("profile="))),
        scenes=tuple(scenes),
        variants=quick.variants,
        expected_runtime="seconds per run (tests only)",
        command=f"study run {study} --profile smoke",
        baseline=quick.baseline,
    )


def parse_study(raw: Any, path: Path, sets: dict[str, Any] | None = None) -> StudySpec:
    """Validate a loaded study file and build its spec (overrides are checked by composing)."""
    where = str(path)
    f = study_file.read(study_file.scene_sets(raw, sets or {}, where), where)
    require(f.name == path.stem, where, f"name '{f.name}' must match the file name")
    variants = _variants(f.variants, f"{where}: variants")
    require("quick" in f.profiles and "paper" in f.profiles, f"{where}: profiles", "needs quick and paper")
    profiles: dict[str, ProfileSpec] = {}
    for name, praw in f.profiles.items():
        require(name in PROFILES, f"{where}: profiles.{name}", f"unknown profile (use {', '.join(PROFILES)})")
        profiles[name] = _profile(name, praw, f"{where}: profiles.{name}", variants)
    if "smoke" not in profiles:
        profiles["smoke"] = _smoke_from_quick(profiles["quick"], f.name)
    for name, p in profiles.items():
        if not p.baseline:
            profiles[name] = p = dataclasses.replace(p, baseline=f.baseline)
        require(p.baseline in p.variants, f"{where}: baseline", f"'{p.baseline}' is not a variant of {p.name}")
    require(f.table.layout in TABLE_LAYOUTS, f"{where}: table.layout", f"must be one of {', '.join(TABLE_LAYOUTS)}")
    for p in f.plots:
        require(p in PLOTS, f"{where}: plots", f"unknown plot '{p}' (use {', '.join(PLOTS)})")
    all_variants = {v for p in profiles.values() for v in p.variants}
    return StudySpec(
        name=f.name,
        question=" ".join(f.question.split()),
        baseline=f.baseline,
        base_seed=f.base_seed,
        metrics=tuple(f.metrics),
        table=TableSpec(layout=f.table.layout, metrics=tuple(f.table.metrics), unranked=tuple(f.table.unranked)),
        plots=tuple(f.plots),
        diagnostics=tuple(f.diagnostics),
        profiles=profiles,
        notes=" ".join(f.notes.split()),
        path=path,
        claims=_claims(f.claims, f"{where}: claims", all_variants),
        variance=_variance(f.variance_components, f"{where}: variance_components", all_variants),
    )


def _variance(raw: VarianceFile | None, where: str, variants: set[str]) -> VarianceSpec | None:
    """Check ``variance_components:`` (variants: those of any profile)."""
    if raw is None:
        return None
    require(len(raw.hardware) >= 2, f"{where}.hardware", "needs at least two dispatch variants")
    for key, v in [("optimisation", raw.optimisation), ("initialisation", raw.initialisation)] + \
            [("hardware", h) for h in raw.hardware]:
        require(v in variants, f"{where}.{key}", f"unknown variant '{v}' (have {', '.join(sorted(variants))})")
    return VarianceSpec(raw.metric, raw.optimisation, raw.initialisation, tuple(raw.hardware))


def _paper(raw: PaperFile | None, where: str) -> PaperClaim | None:
    if raw is None:
        return None
    rows = []
    for r in raw.rows:
        require(r.n is None or r.n >= 2, f"{where}.rows.{r.dataset}.n", "needs at least 2 runs")
        require((r.a_std is None) == (r.b_std is None) or r.b is None, f"{where}.rows.{r.dataset}",
                "give both a_std and b_std, or neither")
        rows.append(PaperRow(r.dataset, r.a, r.b, r.a_std, r.b_std, r.n, r.run_sd, r.run_sd_n, r.scene, r.note))
    return PaperClaim(" ".join(raw.statement.split()), raw.source, tuple(rows))


def _claims(raw: list[ClaimFile], where: str, variants: set[str]) -> tuple[ClaimSpec, ...]:
    """Check a study's ``claims:`` (variants: those of any profile)."""
    out: list[ClaimSpec] = []
    for c in raw:
        at = f"{where}.{c.id}"
        require(bool(NAME_PATTERN.match(c.id)) and c.id not in {o.id for o in out}, at,
                "claim ids must be unique names")
        require(c.test in CLAIM_TESTS, f"{at}.test", f"unknown comparison '{c.test}' (use {', '.join(CLAIM_TESTS)})")
        require(c.expect in CLAIM_TESTS[c.test], f"{at}.expect",
                f"'{c.expect}' is not an expectation of a {c.test} test (use {', '.join(CLAIM_TESTS[c.test])})")
        require(c.group in CLAIM_GROUPS, f"{at}.group", f"unknown group '{c.group}' (use {', '.join(CLAIM_GROUPS)})")
        require(c.sesoi > 0, f"{at}.sesoi", "the smallest effect of interest must be positive")
        for key, metric in (("metric", c.metric), ("versus", c.versus)):
            require(metric in claimable() or (key == "versus" and not metric), f"{at}.{key}",
                    f"unknown metric '{metric}' (use {', '.join(claimable())})")
        used = [c.a, c.b, *(v for w in c.contrasts for v in w)]
        for v in used:
            require(not v or v in variants, at, f"unknown variant '{v}' (have {', '.join(sorted(variants))})")
        require(c.pair in ("seed", "none"), f"{at}.pair", "must be 'seed' or 'none'")
        if c.test == "decoupled":
            require(bool(c.versus), at, "a decoupled claim needs 'versus' (the metric that differs)")
        elif c.test == "contrast":
            require(bool(c.contrasts) and all(isinstance(k, (int, float)) for w in c.contrasts for k in w.values())
                    and all(abs(sum(w.values())) < 1e-9 for w in c.contrasts), f"{at}.contrasts",
                    "needs maps of variant -> number weights that each sum to 0")
        else:
            require(bool(c.a), f"{at}.a", f"a {c.test} claim needs variant 'a'")
            require(bool(c.b) or c.test == "mean", f"{at}.b", f"a {c.test} claim needs variant 'b'")
        if c.test == "interaction":
            require(len(c.scenes) == 2, f"{at}.scenes", "an interaction needs exactly two scenes")
        requires = None
        if c.requires is not None:
            require(c.requires.metric in claimable(), f"{at}.requires.metric", f"unknown metric '{c.requires.metric}'")
            requires = (c.requires.metric, float(c.requires.min))
        out.append(ClaimSpec(
            id=c.id, statement=" ".join(c.claim.split()), metric=c.metric, test=c.test, expect=c.expect, a=c.a,
            b=c.b, scenes=tuple(c.scenes), pair=c.pair, versus=c.versus, sesoi=float(c.sesoi),
            sesoi_source=" ".join(c.sesoi_source.split()), group=c.group, paper=_paper(c.paper, f"{at}.paper"),
            contrasts=tuple(tuple((v, float(k)) for v, k in w.items()) for w in c.contrasts), requires=requires,
            needs=c.needs,
        ))
    return tuple(out)
