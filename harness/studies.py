"""Study definitions: load ``studies/<name>.yaml`` and expand it into runs.

A study file is plain data (see ``studies/secret5.yaml``): a question, named variants
(lists of Hydra override strings, one of them the baseline), per-profile scenes, seed
counts, overrides, expected runtime and the exact command, plus what the report shows.
``expand()`` turns one (study, profile) into ``RunSpec``s, one per seed x scene x variant;
run ``r`` uses seed ``base_seed + r``.

Scenes are either synthetic (``synth: {preset, seed, layout, n_cameras, color_shift, ...}``:
arguments of ``ftgspp.data.synthetic.generate``, generated on demand into
``data/synth/<name>``) or given by overrides (``data.path=${oc.env:DYNERF_ROOT}/...``). A
profile's ``scenes`` may also name a shared set in ``studies/_scene_sets.yaml``.
A study may list ``claims:`` (the paper's statements as data, see ``ClaimSpec``);
``harness.claims`` tests them and ``study report`` gives each a verdict.
The ``smoke`` profile is derived from ``quick`` when a study does not define one:
``profile=smoke`` (at full resolution), one seed and tiny synthetic scenes (64x48 pixels,
6 frames, 5 cameras).
"""

from __future__ import annotations

import dataclasses
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ftgspp.errors import InputError

STUDIES_DIR = Path(os.environ.get("FTGSPP_STUDIES", Path(__file__).resolve().parents[1] / "studies"))
SCENE_SETS_FILE = "_scene_sets.yaml"
PROFILES = ("quick", "paper", "smoke")
TINY_SYNTH = {"width": 64, "height": 48, "n_frames": 6, "n_cameras": 5}
SYNTH_ROOT = Path("data/synth")
# the smoke scenes are generated at 64x48 already: train them at full resolution
SMOKE_OVERRIDES = ("profile=smoke", "data.downsample=1")
LAYOUTS = ("variants_x_scenes", "metrics_x_scenes", "variants_x_metrics")
PLOTS = ("strip", "speed_accuracy", "stability")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")
# claims: test kinds, the expectations each allows, and the metrics a claim may name
CLAIM_TESTS = {"mean": ("higher", "lower"), "variance": ("higher", "lower"),
               "interaction": ("higher", "lower"), "correlation": ("weak",)}
CLAIM_METRICS = (
    "psnr", "ssim1", "ssim2", "dssim1", "dssim2", "lpips_alex", "lpips_vgg", "lpips_alex_01", "lpips_vgg_01",
    "train_seconds", "iters_per_second", "peak_rss_mb", "n_gaussians",
    # diagnostics (ftgspp.diagnostics via the trainer) and the report's per-run convention gaps
    "lifetime_long_on_static", "lifetime_short_on_dynamic", "lifetime_median_fraction",
    "lifetime_partition_contrast", "lifetime_short_share_dynamic", "lifetime_short_share_static",
    "motion_epe_dynamic", "motion_leak_static", "motion_role_switch", "xt_slice_mae",
    "flicker_static", "flicker_static_gt",
    "gap_lpips_alex", "gap_lpips_vgg", "gap_ssim", "gap_dssim",
)


@dataclass(frozen=True)
class SceneSpec:
    """One scene (or difficulty cell) of a profile."""

    name: str
    synth: dict[str, Any] | None = None  # generator args: preset, seed, layout, width, ...
    overrides: tuple[str, ...] = ()  # e.g. data.path=..., lr.scale=3
    label: str = ""  # human-readable column title (default: name)
    synth_dir: str = ""  # where the synthetic scene lives, relative to the working directory
    seeds: int | None = None  # this scene's seed count (default: the profile's; --seeds wins)
    variants: tuple[str, ...] = ()  # the variants run on this scene (default: all)
    # stability ladders this cell is a rung of: ladder name -> rung value (e.g. {lr_scale: 3})
    rungs: tuple[tuple[str, float], ...] = ()

    @property
    def title(self) -> str:
        return self.label or self.name

    def data_overrides(self) -> list[str]:
        """Overrides that select this scene's data and conditions."""
        path = [f"data.path={self.synth_dir}"] if self.synth is not None else []
        return path + list(self.overrides)


@dataclass(frozen=True)
class ProfileSpec:
    """How a study runs under one profile (quick, paper, smoke)."""

    name: str
    seeds: int
    overrides: tuple[str, ...]
    scenes: tuple[SceneSpec, ...]
    variants: dict[str, tuple[str, ...]]
    expected_runtime: str = ""
    command: str = ""
    baseline: str = ""
    jobs: int = 1  # parallel runs when `study run` is given no --jobs


@dataclass(frozen=True)
class TableSpec:
    """Which tables the report writes."""

    layout: str = "variants_x_scenes"
    metrics: tuple[str, ...] = ("psnr",)  # fnmatch patterns (e.g. lpips_*)


@dataclass(frozen=True)
class ClaimSpec:
    """One statement of the paper, as a test on the study's runs (``harness.claims``).

    ``test``: ``mean`` (variant ``a`` against ``b``, or against zero when ``b`` is empty),
    ``variance`` (spread of ``a`` against ``b``), ``interaction`` (the ``a`` − ``b`` difference
    on ``scenes[0]`` against the one on ``scenes[1]``) or ``correlation`` (``metric`` against
    ``versus`` over every run: ``weak`` means |r| < ``threshold``). ``expect`` is the
    direction of the first quantity relative to the second (``higher`` / ``lower``).
    ``scenes``: the scenes pooled (empty: every scene with runs). ``pair``: ``seed`` pairs
    runs of ``a`` and ``b`` that share (scene, seed); ``none`` compares them unpaired (Welch).
    """

    id: str
    statement: str
    metric: str
    test: str
    expect: str
    a: str = ""
    b: str = ""
    scenes: tuple[str, ...] = ()
    pair: str = "seed"
    versus: str = ""
    threshold: float = 0.5
    paper_number: str | None = None


@dataclass(frozen=True)
class StudySpec:
    """A parsed study file."""

    name: str
    question: str
    baseline: str  # default baseline variant; a profile may name its own
    base_seed: int
    metrics: tuple[str, ...]
    table: TableSpec
    plots: tuple[str, ...]
    diagnostics: tuple[str, ...]
    profiles: dict[str, ProfileSpec]
    notes: str = ""
    path: Path | None = None
    claims: tuple[ClaimSpec, ...] = ()
    variance: "VarianceSpec | None" = None

    def profile(self, name: str) -> ProfileSpec:
        """The named profile, or an InputError listing the available ones."""
        if name not in self.profiles:
            raise InputError(f"--profile {name}", f"study '{self.name}' has profiles {sorted(self.profiles)}")
        return self.profiles[name]


@dataclass(frozen=True)
class RunSpec:
    """One training run of a study: (variant, scene, seed) with its full override list."""

    study: str
    profile: str
    variant: str
    scene: SceneSpec
    seed: int
    overrides: tuple[str, ...]

    @property
    def key(self) -> tuple[str, str, int]:
        return (self.variant, self.scene.name, self.seed)

    @property
    def label(self) -> str:
        return f"{self.variant}/{self.scene.name}/seed{self.seed}"


def list_studies(studies_dir: Path | None = None) -> list[str]:
    """Names of the study files (``_*.yaml`` files are shared data, not studies)."""
    root = Path(studies_dir or STUDIES_DIR)
    return sorted(p.stem for p in root.glob("*.yaml") if not p.name.startswith("_"))


def load_study(name: str, studies_dir: Path | None = None) -> StudySpec:
    """Parse and validate ``studies/<name>.yaml``; unknown names raise InputError."""
    root = Path(studies_dir or STUDIES_DIR)
    path = root / f"{name}.yaml"
    if name.startswith("_") or not _NAME.match(name) or not path.is_file():
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


def _require(cond: bool, where: str, problem: str) -> None:
    if not cond:
        raise InputError(where, problem)


def _str_list(value: Any, where: str) -> tuple[str, ...]:
    value = [] if value is None else value
    _require(isinstance(value, list) and all(isinstance(v, str) for v in value), where, "must be a list of strings")
    return tuple(value)


def _parse_variants(raw: Any, where: str) -> dict[str, tuple[str, ...]]:
    _require(isinstance(raw, dict) and raw, where, "must map variant names to override lists")
    out = {}
    for name, overrides in raw.items():
        _require(isinstance(name, str) and bool(_NAME.match(name)), f"{where}.{name}", "bad variant name")
        out[name] = _str_list(overrides, f"{where}.{name}")
    return out


def _parse_scene(raw: Any, where: str, profile: str) -> SceneSpec:
    _require(isinstance(raw, dict) and "name" in raw, where, "a scene needs at least a name")
    name = str(raw["name"])
    _require(bool(_NAME.match(name)), where, f"bad scene name '{name}'")
    synth = raw.get("synth")
    _require(synth is None or isinstance(synth, dict), f"{where}.synth", "must be a mapping of generator args")
    overrides = _str_list(raw.get("overrides"), f"{where}.overrides")
    _require(synth is not None or bool(overrides), where, "needs synth args or data overrides")
    synth_dir = ""
    if synth is not None:
        synth = {"preset": "studio", "seed": 0, "layout": "dynerf", **synth}
        suffix = "-smoke" if profile == "smoke" else ""
        synth_dir = (SYNTH_ROOT / f"{name}{suffix}").as_posix()
    seeds = raw.get("seeds")
    _require(seeds is None or (isinstance(seeds, int) and seeds >= 1), f"{where}.seeds", "must be a positive integer")
    variants = _str_list(raw.get("variants"), f"{where}.variants")
    rungs_raw = raw.get("rungs") or {}
    _require(isinstance(rungs_raw, dict) and all(isinstance(k, str) and isinstance(v, (int, float))
                                                  for k, v in rungs_raw.items()),
             f"{where}.rungs", "must map ladder names to numbers (e.g. {lr_scale: 3})")
    rungs = tuple((k, float(v)) for k, v in rungs_raw.items())
    return SceneSpec(name, synth, overrides, str(raw.get("label", "")), synth_dir, seeds, variants, rungs)


def _parse_profile(name: str, raw: Any, where: str, variants: Any, sets: dict[str, Any]) -> ProfileSpec:
    _require(isinstance(raw, dict), where, "must be a mapping")
    scenes_raw = raw.get("scenes")
    if isinstance(scenes_raw, str):
        _require(scenes_raw in sets, f"{where}.scenes", f"unknown scene set '{scenes_raw}' ({SCENE_SETS_FILE})")
        scenes_raw = sets[scenes_raw]
    _require(isinstance(scenes_raw, list) and scenes_raw, f"{where}.scenes", "must be a non-empty list")
    scenes = tuple(_parse_scene(s, f"{where}.scenes[{i}]", name) for i, s in enumerate(scenes_raw))
    names = [s.name for s in scenes]
    _require(len(set(names)) == len(names), f"{where}.scenes", "scene names must be unique")
    seeds = raw.get("seeds", 1)
    _require(isinstance(seeds, int) and seeds >= 1, f"{where}.seeds", "must be a positive integer")
    jobs = raw.get("jobs", 1)
    _require(isinstance(jobs, int) and jobs >= 1, f"{where}.jobs", "must be a positive integer")
    prof_variants = _parse_variants(raw["variants"], f"{where}.variants") if "variants" in raw else variants
    for s in scenes:
        for v in s.variants:
            _require(v in prof_variants, f"{where}.scenes.{s.name}.variants",
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
        scenes.append(SceneSpec(s.name, synth, keep, s.label, (SYNTH_ROOT / f"{s.name}-smoke").as_posix(),
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
    _require(isinstance(raw, dict), where, "a study file must be a mapping")
    for key in ("name", "question", "baseline", "variants", "profiles"):
        _require(key in raw, where, f"missing key '{key}'")
    _require(raw["name"] == path.stem, where, f"name '{raw['name']}' must match the file name")
    variants = _parse_variants(raw["variants"], f"{where}: variants")
    profiles_raw = raw["profiles"]
    _require(isinstance(profiles_raw, dict), f"{where}: profiles", "must be a mapping")
    _require("quick" in profiles_raw and "paper" in profiles_raw, f"{where}: profiles", "needs quick and paper")
    profiles: dict[str, ProfileSpec] = {}
    for name, praw in profiles_raw.items():
        _require(name in PROFILES, f"{where}: profiles.{name}", f"unknown profile (use {', '.join(PROFILES)})")
        profiles[name] = _parse_profile(name, praw, f"{where}: profiles.{name}", variants, sets or {})
    if "smoke" not in profiles:
        profiles["smoke"] = _smoke_from_quick(profiles["quick"], raw["name"])
    for name, p in profiles.items():
        if not p.baseline:
            profiles[name] = p = dataclasses.replace(p, baseline=raw["baseline"])
        _require(p.baseline in p.variants, f"{where}: baseline", f"'{p.baseline}' is not a variant of {p.name}")
    table_raw = raw.get("table") or {}
    table = TableSpec(
        layout=str(table_raw.get("layout", "variants_x_scenes")),
        metrics=_str_list(table_raw.get("metrics", ["psnr"]), f"{where}: table.metrics"),
    )
    _require(table.layout in LAYOUTS, f"{where}: table.layout", f"must be one of {', '.join(LAYOUTS)}")
    plots = _str_list(raw.get("plots"), f"{where}: plots")
    for p in plots:
        _require(p in PLOTS, f"{where}: plots", f"unknown plot '{p}' (use {', '.join(PLOTS)})")
    base_seed = raw.get("base_seed", 0)
    _require(isinstance(base_seed, int), f"{where}: base_seed", "must be an integer")
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


@dataclass(frozen=True)
class VarianceSpec:
    """Which variants isolate each source of run-to-run spread (``harness.variance``)."""

    metric: str
    optimisation: str  # fixed initialisation, the seed varies the optimisation only
    initialisation: str  # the initialisation is re-drawn per seed too
    hardware: tuple[str, ...]  # same seed and initialisation, another CPU kernel dispatch each


def _parse_variance(raw: Any, where: str, variants: set[str]) -> VarianceSpec | None:
    """Validate ``variance_components:`` (variants: those of any profile)."""
    if raw is None:
        return None
    _require(isinstance(raw, dict), where, "must be a mapping")
    for key in ("metric", "optimisation", "initialisation", "hardware"):
        _require(key in raw, where, f"missing key '{key}'")
    hardware = _str_list(raw["hardware"], f"{where}.hardware")
    _require(len(hardware) >= 2, f"{where}.hardware", "needs at least two dispatch variants")
    for key, v in [("optimisation", raw["optimisation"]), ("initialisation", raw["initialisation"])] + \
            [("hardware", h) for h in hardware]:
        _require(v in variants, f"{where}.{key}", f"unknown variant '{v}' (have {', '.join(sorted(variants))})")
    return VarianceSpec(str(raw["metric"]), str(raw["optimisation"]), str(raw["initialisation"]), hardware)


_CLAIM_KEYS = {"id", "claim", "paper_number", "metric", "test", "expect", "a", "b", "scenes", "pair", "versus",
               "threshold"}


def _parse_claims(raw: Any, where: str, variants: set[str]) -> tuple[ClaimSpec, ...]:
    """Validate a study's ``claims:`` list (variants: those of any profile)."""
    if raw is None:
        return ()
    _require(isinstance(raw, list), where, "must be a list of claims")
    out: list[ClaimSpec] = []
    for i, c in enumerate(raw):
        at = f"{where}[{i}]"
        _require(isinstance(c, dict), at, "a claim must be a mapping")
        unknown = sorted(set(c) - _CLAIM_KEYS)
        _require(not unknown, at, f"unknown key(s) {', '.join(unknown)} (use {', '.join(sorted(_CLAIM_KEYS))})")
        for key in ("id", "claim", "metric", "test", "expect"):
            _require(key in c, at, f"missing key '{key}'")
        cid, test, expect = str(c["id"]), str(c["test"]), str(c["expect"])
        at = f"{where}.{cid}"
        _require(bool(_NAME.match(cid)) and cid not in {o.id for o in out}, at, "claim ids must be unique names")
        _require(test in CLAIM_TESTS, f"{at}.test", f"unknown comparison '{test}' (use {', '.join(CLAIM_TESTS)})")
        _require(expect in CLAIM_TESTS[test], f"{at}.expect",
                 f"'{expect}' is not an expectation of a {test} test (use {', '.join(CLAIM_TESTS[test])})")
        for key in ("metric", "versus"):
            if key in c or key == "metric":
                _require(c[key] in CLAIM_METRICS, f"{at}.{key}",
                         f"unknown metric '{c[key]}' (use {', '.join(CLAIM_METRICS)})")
        a, b = str(c.get("a") or ""), str(c.get("b") or "")
        for key, v in (("a", a), ("b", b)):
            _require(not v or v in variants, f"{at}.{key}", f"unknown variant '{v}' (have {', '.join(sorted(variants))})")
        scenes = _str_list(c.get("scenes"), f"{at}.scenes")
        pair = str(c.get("pair", "seed"))
        _require(pair in ("seed", "none"), f"{at}.pair", "must be 'seed' or 'none'")
        if test == "correlation":
            _require("versus" in c, at, "a correlation claim needs 'versus' (the second metric)")
        else:
            _require(bool(a), f"{at}.a", f"a {test} claim needs variant 'a'")
            _require(bool(b) or test == "mean", f"{at}.b", f"a {test} claim needs variant 'b'")
        if test == "interaction":
            _require(len(scenes) == 2, f"{at}.scenes", "an interaction needs exactly two scenes")
        threshold = c.get("threshold", 0.5)
        _require(isinstance(threshold, (int, float)) and 0 < threshold < 1, f"{at}.threshold", "must be in (0, 1)")
        number = c.get("paper_number")
        out.append(ClaimSpec(
            id=cid, statement=" ".join(str(c["claim"]).split()), metric=str(c["metric"]), test=test,
            expect=expect, a=a, b=b, scenes=scenes, pair=pair, versus=str(c.get("versus", "")),
            threshold=float(threshold), paper_number=None if number is None else str(number),
        ))  # fmt: skip
    return tuple(out)


@dataclass
class Selection:
    """What one invocation asks for on top of the study file."""

    profile: str = "quick"
    seeds: int | None = None  # None: the profile's count
    scenes: list[str] = field(default_factory=list)  # empty: all
    variants: list[str] = field(default_factory=list)  # empty: all
    overrides: list[str] = field(default_factory=list)  # appended to every run


def _pick(requested: list[str], available: list[str], what: str) -> list[str]:
    for name in requested:
        _require(name in available, f"--{what}s {name}", f"unknown {what} (available: {', '.join(available)})")
    return [a for a in available if not requested or a in requested]


def expand(study: StudySpec, sel: Selection) -> list[RunSpec]:
    """All runs of ``study`` for ``sel``: seed-major, then scene, then variant.

    A scene may name its own seed count and the subset of variants run on it (ladder rungs
    with fewer seeds, a tuning scene with its own sweep); ``--seeds`` sets every scene's.
    """
    prof = study.profile(sel.profile)
    for o in sel.overrides:
        _require("=" in o, f"override '{o}'", "expected key=value")
        _require(not o.lstrip("+~").startswith("seed="), f"override '{o}'",
                 "seeds come from --seeds and the study's base_seed")
    variants = _pick(sel.variants, list(prof.variants), "variant")
    scene_names = _pick(sel.scenes, [s.name for s in prof.scenes], "scene")
    scenes = [s for s in prof.scenes if s.name in scene_names]
    _require(sel.seeds is None or sel.seeds >= 1, "--seeds", "must be at least 1")

    def seeds_of(scene: SceneSpec) -> int:
        return sel.seeds if sel.seeds is not None else scene.seeds or prof.seeds

    runs = []
    for r in range(max(seeds_of(s) for s in scenes)):
        seed = study.base_seed + r
        for scene in scenes:
            if r >= seeds_of(scene):
                continue
            for variant in variants:
                if scene.variants and variant not in scene.variants:
                    continue
                overrides = (
                    *prof.overrides,
                    *scene.data_overrides(),
                    *prof.variants[variant],
                    *sel.overrides,
                    f"seed={seed}",
                )
                runs.append(RunSpec(study.name, prof.name, variant, scene, seed, overrides))
    _require(bool(runs), f"--scenes {','.join(scene_names)} --variants {','.join(variants)}",
             "no run of the study has this scene and variant (a scene may run only some variants: study list)")
    return runs


def describe_runs(runs: list[RunSpec]) -> str:
    """``"12 runs = 2 variants x 3 scenes x 2 seeds"``, or ``"... up to ..."`` when scenes
    carry their own seed counts or variant subsets and the runs are not the full product."""
    if not runs:
        return "0 runs"
    n_var, n_scene, n_seed = (len(set(x)) for x in zip(*(r.key for r in runs)))
    full = n_var * n_scene * n_seed == len(runs)
    return (f"{len(runs)} runs = {n_var} variants x {n_scene} scenes x {n_seed} seeds" if full else
            f"{len(runs)} runs over {n_var} variants x {n_scene} scenes, up to {n_seed} seeds (per-scene seeds and variants)")
