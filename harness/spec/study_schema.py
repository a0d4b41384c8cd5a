"""The schema of a study file (``studies/<name>.yaml``), which is also the validated spec.

A study file is plain data (see ``studies/secret5.yaml``): a question, named variants (lists
of Hydra override strings, one of them the baseline), per-profile scenes, seed counts,
overrides, expected runtime and the exact command, plus what the report shows. Scenes are
either synthetic (``synth: {preset, seed, layout, n_cameras, color_shift, ...}``: arguments of
``ftgspp.data.synthetic.build.generate``, generated on demand into ``data/synth/<name>``) or given
by overrides (``data.path=${oc.env:DYNERF_ROOT}/...``). A study may list ``claims:`` (the
paper's statements as data, ``ClaimSpec``) and ``variance_components:`` (``VarianceSpec``).

Read it top to bottom: ``StudySpec`` (last) is the whole file. The frozen dataclasses below
are what OmegaConf type-checks a file against and what the rest of the harness consumes; a
field's type is the type the harness holds. Where the file writes a field differently,
``key(...)`` says how (another key name, another shape read by a function, or mandatory in
the file although Python callers may leave it out); ``derived(...)`` marks what the loader
fills in and a file may not set (both from ``spec.structured``). Closed sets of values are
``StrEnum``s whose members are named as their values (OmegaConf converts a string by member
name); a member compares equal to its string and prints as it. ``spec.study_files`` reads a
file onto these classes and checks in one pass what types cannot: names that must refer to
variants, scenes, metrics and ladders.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum, nonmember
from pathlib import Path
from typing import Any

from ftgspp.errors import InputError
from harness.spec.structured import derived, key

SYNTH_ROOT = Path("data/synth")  # a synthetic scene lives in SYNTH_ROOT/<name> (smoke: <name>-smoke)
JOBS_SPEEDUP = 1.36  # throughput of 2 parallel runs over 1 on 2 cores (BENCHMARKS.md); more: no more


def pairs(mapping: dict[str, Any]) -> tuple[tuple[str, Any], ...]:
    """``{a: 1, b: 2}`` as ``(("a", 1), ("b", 2))``: hashable, in the file's order."""
    return tuple(mapping.items())


# --- closed sets of values; ``noun`` is what an error calls one of them -----------------------


class ProfileName(StrEnum):
    """How long a study runs: ``quick`` (CPU, synthetic scenes), ``paper`` (real data, GPU),
    ``smoke`` (tests; derived from ``quick`` when a file has none)."""

    noun = nonmember("profile")
    quick = "quick"
    paper = "paper"
    smoke = "smoke"


class TableLayout(StrEnum):
    """The report's tables (docs/studies.md)."""

    noun = nonmember("table layout")
    variants_x_scenes = "variants_x_scenes"  # a row per variant, a column per scene; a table per metric
    metrics_x_scenes = "metrics_x_scenes"  # a row per metric (baseline variant), no ranking
    variants_x_metrics = "variants_x_metrics"  # a row per variant, metrics at the scene average


class Plot(StrEnum):
    """A figure the report draws."""

    noun = nonmember("plot")
    strip = "strip"
    speed_accuracy = "speed_accuracy"
    stability = "stability"


class Comparison(StrEnum):
    """A claim's test (``ClaimSpec.test``)."""

    noun = nonmember("comparison")
    mean = "mean"
    variance = "variance"
    interaction = "interaction"
    contrast = "contrast"
    decoupled = "decoupled"


class Expectation(StrEnum):
    """What a claim expects of ``a`` relative to ``b`` (``ClaimSpec.expect``)."""

    noun = nonmember("expectation")
    higher = "higher"
    lower = "lower"
    not_higher = "not_higher"  # equivalent counts as reproduced
    not_lower = "not_lower"
    exists = "exists"  # decoupled claims


class ClaimGroup(StrEnum):
    """The family a claim's p-values are corrected in (``analysis.verdicts``)."""

    noun = nonmember("group")
    paper = "paper"
    extension = "extension"
    convention = "convention"


class Pairing(StrEnum):
    """How a mean claim pairs the runs of ``a`` and ``b``: by seed, or not at all (Welch)."""

    noun = nonmember("pairing")
    seed = "seed"
    none = "none"


PROFILES = tuple(p.value for p in ProfileName)  # plain strings (argparse choices)
DIRECTIONS = (Expectation.higher, Expectation.lower, Expectation.not_higher, Expectation.not_lower)
EXPECTATIONS = {Comparison.mean: DIRECTIONS, Comparison.variance: DIRECTIONS, Comparison.interaction: DIRECTIONS,
                Comparison.contrast: (Expectation.higher, Expectation.lower),
                Comparison.decoupled: (Expectation.exists,)}
CLAIM_GROUPS = {ClaimGroup.paper: "the paper's method claims", ClaimGroup.extension: "this project's own extensions",
                ClaimGroup.convention: "metric conventions"}


# --- scenes and profiles -----------------------------------------------------------------------


@dataclass(frozen=True)
class Ladder:
    """What a rung value of one stability ladder sets: an override or a synthetic-scene argument.

    ``override: lr.scale, times: 2`` makes the rung ``{lr_scale: 3}`` the override
    ``lr.scale=6.0``; ``synth: n_cameras`` makes ``{cameras: 6}`` the generator argument
    ``n_cameras: 6``. A rung at ``base`` sets nothing (the profile's own value).
    """

    override: str = ""
    synth: str = ""
    times: float = 1.0
    base: float | None = None


@dataclass(frozen=True)
class StudyScene:
    """One scene (or difficulty cell) of a profile: ``{name: studio, synth: {preset: studio}}``."""

    name: str
    synth: dict[str, Any] | None = None  # generator args: preset (studio), seed (0), layout (dynerf), width, ...
    overrides: tuple[str, ...] = ()  # e.g. data.path=..., lr.scale=3; then what the rungs set
    label: str = ""  # human-readable column title (default: name)
    synth_dir: str = derived("")  # where the synthetic scene lives, relative to the working directory
    seeds: int | None = None  # this scene's seed count (default: the profile's; --seeds wins)
    variants: tuple[str, ...] = ()  # the variants run on this scene (default: all)
    # stability ladders this cell is a rung of: ladder name -> rung value (file: {lr_scale: 3})
    rungs: tuple[tuple[str, float], ...] = key(default=(), written=dict[str, float], read=pairs)

    @property
    def title(self) -> str:
        return self.label or self.name

    def data_overrides(self) -> list[str]:
        """Overrides that select this scene's data and conditions."""
        path = [f"data.path={self.synth_dir}"] if self.synth is not None else []
        return path + list(self.overrides)


def jobs_speedup(jobs: int) -> float:
    """Measured throughput factor of ``jobs`` parallel runs on a 2-core machine."""
    return JOBS_SPEEDUP if jobs >= 2 else 1.0


def plural(n: int, word: str) -> str:
    """``1 scene``, ``2 scenes``."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def fmt_duration(seconds: float) -> str:
    """``75 -> '1 min'``, ``3700 -> '1 h 02 min'``, ``40 -> '40 s'``."""
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{round(s / 60)} min"
    return f"{s // 3600} h {round((s % 3600) / 60):02d} min"


@dataclass(frozen=True)
class ProfileSpec:
    """How a study runs under one profile (quick, paper, smoke)."""

    name: str = derived("")  # the profile's key in ``profiles:``
    seeds: int = 1
    overrides: tuple[str, ...] = ()
    # the scenes, or the name of a shared list in studies/_scene_sets.yaml
    scenes: tuple[StudyScene, ...] = key(default=(), required=True)
    # default: the study's variants (file: omitted)
    variants: dict[str, tuple[str, ...]] = key(factory=dict, written=dict[str, tuple[str, ...]] | None)
    expected_runtime: str = ""  # a note for people (GPU profiles); the estimate comes from run_seconds
    command: str = ""
    baseline: str = ""  # default: the study's
    jobs: int = 1  # parallel runs when `study run` is given no --jobs
    # wall seconds per run, one at a time, on ``machine`` (0: unknown); `study run` estimates a quick
    # profile from the rate measured for its host's kind instead (run.progress.expected, spec.throughput)
    run_seconds: float = 0.0
    machine: str = "an idle 2-core CPU machine (the study file's own figure)"
    ladders: dict[str, Ladder] = field(default_factory=dict)  # what the scenes' rungs set

    def estimate(self, n_runs: int, jobs: int) -> str:
        """``~13 min (25 runs x ~40 s, 2 at a time) on <machine>``, or the profile's note."""
        if self.run_seconds <= 0:
            return self.expected_runtime or "unknown"
        total = n_runs * self.run_seconds / jobs_speedup(jobs)
        at = f", {jobs} at a time" if jobs > 1 else ""
        return f"~{fmt_duration(total)} ({plural(n_runs, 'run')} x ~{self.run_seconds:.0f} s{at}) on {self.machine}"


@dataclass(frozen=True)
class TableSpec:
    """Which tables the report writes."""

    layout: TableLayout = TableLayout.variants_x_scenes
    metrics: tuple[str, ...] = ("psnr",)  # fnmatch patterns (e.g. lpips_*)
    unranked: tuple[str, ...] = ()  # variants shown but never ranked (hardware controls, not methods)


# --- claims and sources of spread --------------------------------------------------------------


@dataclass(frozen=True)
class PaperRow:
    """What the paper reports for one dataset: the compared values, their spread and runs.

    ``a`` and ``b`` are the paper's values of the claim's two sides (``b`` None: ``a`` is
    the effect itself); ``a_std``/``b_std`` with ``n`` runs per arm where the paper gives a
    spread. Where it gives none, ``run_sd`` is the paper's own run-to-run SD on that dataset
    (``run_sd_n`` runs; e.g. from its colour-correction stability table), used for both arms.
    ``scene``: our synthetic scene that stands in for the dataset.
    """

    dataset: str
    a: float | None = None
    b: float | None = None
    a_std: float | None = None
    b_std: float | None = None
    n: int | None = None
    run_sd: float | None = None
    run_sd_n: int | None = None
    scene: str = ""
    note: str = ""

    @property
    def effect(self) -> float | None:
        """The paper's effect a − b (or a), None when it gives no number."""
        if self.a is None:
            return None
        return self.a - (self.b or 0.0)


@dataclass(frozen=True)
class PaperClaim:
    """The paper's statement (paraphrased, whitespace normalised), where it makes it, and its
    numbers per dataset."""

    statement: str
    source: str
    rows: tuple[PaperRow, ...] = ()


@dataclass(frozen=True)
class Requires:
    """How a claim's ``requires:`` is written: ``{metric: relocated_total, min: 1000}``."""

    metric: str
    min: float


@dataclass(frozen=True)
class ClaimSpec:
    """One statement, as a test on the study's runs (``analysis.claim_tests``).

    ``test``: ``mean`` (variant ``a`` against ``b``, or against zero when ``b`` is empty),
    ``variance`` (spread of ``a`` against ``b``), ``interaction`` (the ``a`` − ``b``
    difference on ``scenes[0]`` against the one on ``scenes[1]``), ``contrast`` (every
    weighted sum of variants in ``contrasts`` per (scene, seed); all must hold: "CC gives the
    largest gain") or ``decoupled`` (on some scene, two variants are equivalent in ``metric``
    within ±``sesoi`` yet differ in ``versus``: "clean RGB does not imply clean motion").
    ``expect``: ``higher`` / ``lower`` (a relative to b), ``not_higher`` / ``not_lower``
    (equivalent counts as reproduced), ``exists`` (decoupled); ``EXPECTATIONS`` per test.
    ``sesoi``: the smallest effect of interest in the effect's units, fixed in the study file
    before the runs (``sesoi_source`` says where it comes from); ``group`` names the family
    the claim is corrected in (``CLAIM_GROUPS``). ``requires``: a metric whose median over the
    claim's runs must reach a value for the claim's mechanism to be present on the scene (else
    "not exercised"). ``statement`` (file key ``claim``) and ``sesoi_source`` are whitespace
    normalised.
    """

    id: str
    statement: str = key("claim")
    metric: str
    test: Comparison
    expect: Expectation
    a: str = ""
    b: str = ""
    scenes: tuple[str, ...] = ()
    pair: Pairing = Pairing.seed
    versus: str = ""
    sesoi: float = key(default=0.1, required=True)
    sesoi_source: str = key(default="", required=True)
    group: ClaimGroup = ClaimGroup.paper
    paper: PaperClaim | None = None
    # each a map variant -> weight summing to 0 (file: [{cc: 1, baseline: -1}])
    contrasts: tuple[tuple[tuple[str, float], ...], ...] = key(
        default=(), written=list[dict[str, Any]], read=lambda weights: tuple(map(pairs, weights)))
    requires: tuple[str, float] | None = key(default=None, written=Requires | None,
                                             read=lambda r: (r.metric, r.min))
    needs: str = ""  # real data the claim needs; "not tested" rows say so


@dataclass(frozen=True)
class VarianceSpec:
    """Which variants isolate each source of run-to-run spread (``analysis.variance``)."""

    metric: str
    optimisation: str  # fixed initialisation, the seed varies the optimisation only
    initialisation: str  # the initialisation is re-drawn per seed too
    hardware: tuple[str, ...]  # same seed and initialisation, another CPU kernel dispatch each


# --- the whole file ----------------------------------------------------------------------------


@dataclass(frozen=True)
class StudySpec:
    """A study file: ``name`` is the file's name, ``question`` and ``notes`` are whitespace
    normalised, ``path`` is where it was read from."""

    name: str
    question: str
    baseline: str  # default baseline variant; a profile may name its own
    base_seed: int = 0  # run r uses seed base_seed + r
    metrics: tuple[str, ...] = ("psnr",)  # fnmatch patterns
    table: TableSpec = field(default_factory=TableSpec)
    plots: tuple[Plot, ...] = ()
    diagnostics: tuple[str, ...] = ()  # images the runs logged under the diagnostics/ artifact path
    profiles: dict[str, ProfileSpec] = key(factory=dict, required=True, written=dict[ProfileName, ProfileSpec])
    notes: str = ""
    path: Path | None = derived(None)
    claims: tuple[ClaimSpec, ...] = ()
    variance: VarianceSpec | None = key("variance_components", default=None)
    variants: dict[str, tuple[str, ...]] = key(factory=dict, required=True)  # name -> Hydra overrides

    def profile(self, name: str) -> ProfileSpec:
        """The named profile, or an InputError listing the available ones."""
        if name not in self.profiles:
            raise InputError(f"--profile {name}", f"study '{self.name}' has profiles {sorted(self.profiles)}")
        return self.profiles[name]
