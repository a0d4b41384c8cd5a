"""Read and validate ``studies/<name>.yaml`` into a ``StudySpec``.

``load_study(name)`` parses the file; every problem is one ``InputError`` naming the key
(``study run`` prints it as one line and exits 2). A profile's ``scenes`` may name a shared
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
from harness.spec.study import (
    CLAIM_METRICS,
    CLAIM_TESTS,
    NAME_PATTERN,
    PLOTS,
    PROFILES,
    SMOKE_OVERRIDES,
    SYNTH_ROOT,
    TABLE_LAYOUTS,
    TINY_SYNTH,
    ClaimSpec,
    ProfileSpec,
    StudyScene,
    StudySpec,
    TableSpec,
    VarianceSpec,
)

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


def _str_list(value: Any, where: str) -> tuple[str, ...]:
    value = [] if value is None else value
    require(isinstance(value, list) and all(isinstance(v, str) for v in value), where, "must be a list of strings")
    return tuple(value)


def _parse_variants(raw: Any, where: str) -> dict[str, tuple[str, ...]]:
    require(isinstance(raw, dict) and raw, where, "must map variant names to override lists")
    out = {}
    for name, overrides in raw.items():
        require(isinstance(name, str) and bool(NAME_PATTERN.match(name)), f"{where}.{name}", "bad variant name")
        out[name] = _str_list(overrides, f"{where}.{name}")
    return out


def _parse_scene(raw: Any, where: str, profile: str) -> StudyScene:
    require(isinstance(raw, dict) and "name" in raw, where, "a scene needs at least a name")
    name = str(raw["name"])
    require(bool(NAME_PATTERN.match(name)), where, f"bad scene name '{name}'")
    synth = raw.get("synth")
    require(synth is None or isinstance(synth, dict), f"{where}.synth", "must be a mapping of generator args")
    overrides = _str_list(raw.get("overrides"), f"{where}.overrides")
    require(synth is not None or bool(overrides), where, "needs synth args or data overrides")
    synth_dir = ""
    if synth is not None:
        synth = {"preset": "studio", "seed": 0, "layout": "dynerf", **synth}
        suffix = "-smoke" if profile == "smoke" else ""
        synth_dir = (SYNTH_ROOT / f"{name}{suffix}").as_posix()
    seeds = raw.get("seeds")
    require(seeds is None or (isinstance(seeds, int) and seeds >= 1), f"{where}.seeds", "must be a positive integer")
    variants = _str_list(raw.get("variants"), f"{where}.variants")
    rungs_raw = raw.get("rungs") or {}
    require(isinstance(rungs_raw, dict) and all(isinstance(k, str) and isinstance(v, (int, float))
                                                  for k, v in rungs_raw.items()),
             f"{where}.rungs", "must map ladder names to numbers (e.g. {lr_scale: 3})")
    rungs = tuple((k, float(v)) for k, v in rungs_raw.items())
    return StudyScene(name, synth, overrides, str(raw.get("label", "")), synth_dir, seeds, variants, rungs)


def _parse_profile(name: str, raw: Any, where: str, variants: Any, sets: dict[str, Any]) -> ProfileSpec:
    require(isinstance(raw, dict), where, "must be a mapping")
    scenes_raw = raw.get("scenes")
    if isinstance(scenes_raw, str):
        require(scenes_raw in sets, f"{where}.scenes", f"unknown scene set '{scenes_raw}' ({SCENE_SETS_FILE})")
        scenes_raw = sets[scenes_raw]
    require(isinstance(scenes_raw, list) and scenes_raw, f"{where}.scenes", "must be a non-empty list")
    scenes = tuple(_parse_scene(s, f"{where}.scenes[{i}]", name) for i, s in enumerate(scenes_raw))
    names = [s.name for s in scenes]
    require(len(set(names)) == len(names), f"{where}.scenes", "scene names must be unique")
    seeds = raw.get("seeds", 1)
    require(isinstance(seeds, int) and seeds >= 1, f"{where}.seeds", "must be a positive integer")
    jobs = raw.get("jobs", 1)
    require(isinstance(jobs, int) and jobs >= 1, f"{where}.jobs", "must be a positive integer")
    prof_variants = _parse_variants(raw["variants"], f"{where}.variants") if "variants" in raw else variants
    for s in scenes:
        for v in s.variants:
            require(v in prof_variants, f"{where}.scenes.{s.name}.variants",
                     f"unknown variant '{v}' (have {', '.join(prof_variants)})")
    return ProfileSpec(
        name=name,
        seeds=seeds,
        overrides=_str_list(raw.get("overrides"), f"{where}.overrides"),
        scenes=scenes,
        variants=prof_variants,
        expected_runtime=str(raw.get("expected_runtime", "")),
        command=str(raw.get("command", "")),
        baseline=str(raw.get("baseline", "")),
        jobs=jobs,
    )


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
    """Validate the structure of a loaded study file (overrides are checked by composing)."""
    where = str(path)
    require(isinstance(raw, dict), where, "a study file must be a mapping")
    for key in ("name", "question", "baseline", "variants", "profiles"):
        require(key in raw, where, f"missing key '{key}'")
    require(raw["name"] == path.stem, where, f"name '{raw['name']}' must match the file name")
    variants = _parse_variants(raw["variants"], f"{where}: variants")
    profiles_raw = raw["profiles"]
    require(isinstance(profiles_raw, dict), f"{where}: profiles", "must be a mapping")
    require("quick" in profiles_raw and "paper" in profiles_raw, f"{where}: profiles", "needs quick and paper")
    profiles: dict[str, ProfileSpec] = {}
    for name, praw in profiles_raw.items():
        require(name in PROFILES, f"{where}: profiles.{name}", f"unknown profile (use {', '.join(PROFILES)})")
        profiles[name] = _parse_profile(name, praw, f"{where}: profiles.{name}", variants, sets or {})
    if "smoke" not in profiles:
        profiles["smoke"] = _smoke_from_quick(profiles["quick"], raw["name"])
    for name, p in profiles.items():
        if not p.baseline:
            profiles[name] = p = dataclasses.replace(p, baseline=raw["baseline"])
        require(p.baseline in p.variants, f"{where}: baseline", f"'{p.baseline}' is not a variant of {p.name}")
    table_raw = raw.get("table") or {}
    table = TableSpec(
        layout=str(table_raw.get("layout", "variants_x_scenes")),
        metrics=_str_list(table_raw.get("metrics", ["psnr"]), f"{where}: table.metrics"),
    )
    require(table.layout in TABLE_LAYOUTS, f"{where}: table.layout", f"must be one of {', '.join(TABLE_LAYOUTS)}")
    plots = _str_list(raw.get("plots"), f"{where}: plots")
    for p in plots:
        require(p in PLOTS, f"{where}: plots", f"unknown plot '{p}' (use {', '.join(PLOTS)})")
    base_seed = raw.get("base_seed", 0)
    require(isinstance(base_seed, int), f"{where}: base_seed", "must be an integer")
    all_variants = {v for p in profiles.values() for v in p.variants}
    claims = _parse_claims(raw.get("claims"), f"{where}: claims", all_variants)
    variance = _parse_variance(raw.get("variance_components"), f"{where}: variance_components", all_variants)
    return StudySpec(
        name=raw["name"],
        question=" ".join(str(raw["question"]).split()),
        baseline=raw["baseline"],
        base_seed=base_seed,
        metrics=_str_list(raw.get("metrics", ["psnr"]), f"{where}: metrics"),
        table=table,
        plots=plots,
        diagnostics=_str_list(raw.get("diagnostics"), f"{where}: diagnostics"),
        profiles=profiles,
        notes=" ".join(str(raw.get("notes", "")).split()),
        path=path,
        claims=claims,
        variance=variance,
    )


def _parse_variance(raw: Any, where: str, variants: set[str]) -> VarianceSpec | None:
    """Validate ``variance_components:`` (variants: those of any profile)."""
    if raw is None:
        return None
    require(isinstance(raw, dict), where, "must be a mapping")
    for key in ("metric", "optimisation", "initialisation", "hardware"):
        require(key in raw, where, f"missing key '{key}'")
    hardware = _str_list(raw["hardware"], f"{where}.hardware")
    require(len(hardware) >= 2, f"{where}.hardware", "needs at least two dispatch variants")
    for key, v in [("optimisation", raw["optimisation"]), ("initialisation", raw["initialisation"])] + \
            [("hardware", h) for h in hardware]:
        require(v in variants, f"{where}.{key}", f"unknown variant '{v}' (have {', '.join(sorted(variants))})")
    return VarianceSpec(str(raw["metric"]), str(raw["optimisation"]), str(raw["initialisation"]), hardware)


_CLAIM_KEYS = {"id", "claim", "paper_number", "metric", "test", "expect", "a", "b", "scenes", "pair", "versus",
               "threshold"}


def _parse_claims(raw: Any, where: str, variants: set[str]) -> tuple[ClaimSpec, ...]:
    """Validate a study's ``claims:`` list (variants: those of any profile)."""
    if raw is None:
        return ()
    require(isinstance(raw, list), where, "must be a list of claims")
    out: list[ClaimSpec] = []
    for i, c in enumerate(raw):
        at = f"{where}[{i}]"
        require(isinstance(c, dict), at, "a claim must be a mapping")
        unknown = sorted(set(c) - _CLAIM_KEYS)
        require(not unknown, at, f"unknown key(s) {', '.join(unknown)} (use {', '.join(sorted(_CLAIM_KEYS))})")
        for key in ("id", "claim", "metric", "test", "expect"):
            require(key in c, at, f"missing key '{key}'")
        cid, test, expect = str(c["id"]), str(c["test"]), str(c["expect"])
        at = f"{where}.{cid}"
        require(bool(NAME_PATTERN.match(cid)) and cid not in {o.id for o in out}, at, "claim ids must be unique names")
        require(test in CLAIM_TESTS, f"{at}.test", f"unknown comparison '{test}' (use {', '.join(CLAIM_TESTS)})")
        require(expect in CLAIM_TESTS[test], f"{at}.expect",
                 f"'{expect}' is not an expectation of a {test} test (use {', '.join(CLAIM_TESTS[test])})")
        for key in ("metric", "versus"):
            if key in c or key == "metric":
                require(c[key] in CLAIM_METRICS, f"{at}.{key}",
                         f"unknown metric '{c[key]}' (use {', '.join(CLAIM_METRICS)})")
        a, b = str(c.get("a") or ""), str(c.get("b") or "")
        for key, v in (("a", a), ("b", b)):
            require(not v or v in variants, f"{at}.{key}", f"unknown variant '{v}' (have {', '.join(sorted(variants))})")
        scenes = _str_list(c.get("scenes"), f"{at}.scenes")
        pair = str(c.get("pair", "seed"))
        require(pair in ("seed", "none"), f"{at}.pair", "must be 'seed' or 'none'")
        if test == "correlation":
            require("versus" in c, at, "a correlation claim needs 'versus' (the second metric)")
        else:
            require(bool(a), f"{at}.a", f"a {test} claim needs variant 'a'")
            require(bool(b) or test == "mean", f"{at}.b", f"a {test} claim needs variant 'b'")
        if test == "interaction":
            require(len(scenes) == 2, f"{at}.scenes", "an interaction needs exactly two scenes")
        threshold = c.get("threshold", 0.5)
        require(isinstance(threshold, (int, float)) and 0 < threshold < 1, f"{at}.threshold", "must be in (0, 1)")
        number = c.get("paper_number")
        out.append(ClaimSpec(
            id=cid, statement=" ".join(str(c["claim"]).split()), metric=str(c["metric"]), test=test,
            expect=expect, a=a, b=b, scenes=scenes, pair=pair, versus=str(c.get("versus", "")),
            threshold=float(threshold), paper_number=None if number is None else str(number),
        ))  # fmt: skip
    return tuple(out)

