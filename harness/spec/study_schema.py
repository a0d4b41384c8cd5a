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
    xt_grid = "xt_grid"  # per scene: |render − noise-free ground truth| x–t slices, variants × seeds


class Comparison(StrEnum):
    """A claim's test (``ClaimSpec.test``)."""

    noun = nonmember("comparison")
    mean = "mean"
    variance = "variance"
    interaction = "interaction"
    contrast = "contrast"
    decoupled = "decoupled"  # some pair equivalent in the metric, different in ``versus``
    dissociated = "dissociated"  # some pair: the metric not worse (non-inferior), ``versus`` worse
    spread = "spread"  # one variant's run-to-run SD, described beside the paper's (no test)


class Expectation(StrEnum):
    """What a claim expects of ``a`` relative to ``b`` (``ClaimSpec.expect``)."""

    noun = nonmember("expectation")
    higher = "higher"
    lower = "lower"
    not_higher = "not_higher"  # equivalent counts as reproduced
    not_lower = "not_lower"
    equivalent = "equivalent"  # "≈": reproduced by TOST at ±SESOI, contradicted outside it
    exists = "exists"  # decoupled and dissociated claims
    describe = "describe"  # spread: a description, no test


class ClaimGroup(StrEnum):
    """The family a claim's p-values are corrected in (``analysis.verdicts``)."""

    noun = nonmember("group")
    paper = "paper"
    extension = "extension"
    convention = "convention"
    second_method = "second_method"


class Unit(StrEnum):
    """A mean claim's independent unit over several instances of a scene (``ClaimSpec.unit``)."""

    noun = nonmember("unit")
    instance = "instance"
    seed = "seed"


class Pairing(StrEnum):
    """How a mean claim pairs the runs of ``a`` and ``b``: by seed, or not at all (Welch)."""

    noun = nonmember("pairing")
    seed = "seed"
    none = "none"


PROFILES = tuple(p.value for p in ProfileName)  # plain strings (argparse choices)
DIRECTIONS = (Expectation.higher, Expectation.lower, Expectation.not_higher, Expectation.not_lower,
              Expectation.equivalent)
EXPECTATIONS = {Comparison.mean: DIRECTIONS, Comparison.variance: DIRECTIONS, Comparison.interaction: DIRECTIONS,
                Comparison.contrast: (Expectation.higher, Expectation.lower),
                Comparison.decoupled: (Expectation.exists,), Comparison.dissociated: (Expectation.exists,),
                Comparison.spread: (Expectation.describe,)}
CLAIM_GROUPS = {ClaimGroup.paper: "the paper's method claims", ClaimGroup.extension: "this project's own extensions",
                ClaimGroup.convention: "metric conventions",
                ClaimGroup.second_method: "the paper's secrets tested on Spacetime Gaussians (STGS), a second method"}


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
    instances: int = 1  # synthetic instances of this kind of scene, synth seed + i each (``spec.instances``)
    instance_of: str = derived("")  # the scene as written (the claims' name); "" for a scene built in code
    instance: int = derived(0)

    @property
    def title(self) -> str:
        return self.label or self.name

    @property
    def base(self) -> str:
        """The name claims give this scene: the scene it is an instance of."""
        return self.instance_of or self.name

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
class PlanSpec:
    """A mean claim's sequential plan (docs/sequential.md, ``analysis.sequential.Plan``): runs per
    arm (pairs for a paired claim) at the first look, ``per_round`` more a round, at most
    ``rounds`` looks, and caps for the claim (its runs, every arm counted, or CPU hours at the
    profile's ``run_seconds``). A key left out is the profile's ``sequential:`` value, else the
    library's default."""

    first: int | None = None
    per_round: int | None = None
    rounds: int | None = None
    cap_runs: int | None = None
    cap_cpu_hours: float | None = None


@dataclass(frozen=True)
class SequentialSpec(PlanSpec):
    """A profile's ``sequential:`` block: the plan of its counted mean claims (``study decide``)
    and the CPU hours the whole study may use (``--until-decided`` stops before a round beyond it)."""

    study_cap_cpu_hours: float | None = None


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
    sequential: SequentialSpec | None = None  # runs until decided (``study decide``); None: a fixed design

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
class Requires:
    """What must be present on a claim's runs for its mechanism to be exercised (else the
    verdict is "not exercised"): ``{metric: relocated_total, min: 1000}`` — the median over the
    claim's runs reaches ``min``; or ``{metric: flicker_static, above: flicker_static_gt}`` — on
    some arm of the claim, the median of ``metric`` minus its ground-truth level (another metric,
    or a number such as ``"0"``) reaches the metric's smallest effect of interest: the artefact
    the claim is about shows at all."""

    metric: str
    min: float | None = None
    above: str = ""


@dataclass(frozen=True)
class ClaimSpec:
    """One claim, as a test on the study's runs (``analysis.claim_tests``).

    ``test``: ``mean`` (variant ``a`` against ``b``, or against zero when ``b`` is empty),
    ``variance`` (spread of ``a`` against ``b``), ``interaction`` (the ``a`` − ``b``
    difference on ``scenes[0]`` against the one on ``scenes[1]``; ``pairs`` gives each scene its
    own (a, b) where the two scenes run different variants), ``contrast`` (every weighted sum of
    variants in ``contrasts`` per (scene, seed); all must hold: "CC gives the largest gain"),
    ``decoupled`` (on some scene, two variants are equivalent in ``metric`` within ±SESOI yet
    differ in ``versus``), ``dissociated`` (on some scene, one variant is not worse than another
    in ``metric`` — non-inferior at the SESOI — yet worse in ``versus``: "clean RGB does not imply
    clean motion"; both over every pair of the study's variants, or of ``among``) or ``spread``
    (variant ``a``'s run-to-run SD, described beside the paper's).
    ``expect``: ``higher`` / ``lower`` (a relative to b), ``not_higher`` / ``not_lower``
    (equivalent counts as reproduced), ``equivalent`` ("≈": TOST reproduces, the minimal-effect
    test contradicts), ``exists`` (decoupled, dissociated), ``describe`` (spread);
    ``EXPECTATIONS`` per test.
    ``sesoi``: the smallest effect of interest of the claim's metric (or of an SD ratio for
    ``variance``), fixed once per metric in the metric registry (``harness/spec/metrics.py``,
    rationale in docs/sesoi.md) and filled in by the loader; a claim never sets its own.
    ``group`` names the family the claim is corrected in (``CLAIM_GROUPS``); a ``paper`` claim
    belongs to a statement of the paper register (``studies/_paper.yaml``), which says whether it
    decides the statement or is evidence shown inside its row. ``requires``: what must be present
    for the claim's mechanism to be exercised (``Requires``). Whether a claim was registered
    before its runs is not written here: it is computed from git (``spec.registration``: the
    commit that last changed the claim, its arms and scenes, against its first run's commit).
    ``withdrawn``: why it no longer counts — a registered claim is never deleted after its runs,
    its result stays in view. ``history``: what changed and why (notes, not part of the registration).
    ``plan``: a mean claim's sequential plan, over its profile's ``sequential:`` (``PlanSpec``;
    part of the registration). ``unit``: over several instances of a scene, a mean claim tests
    per-instance means (``instance``) or keeps the seed (``seed``: a run-to-run claim).
    ``statement`` (file key ``claim``) is whitespace normalised.
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
    group: ClaimGroup = ClaimGroup.paper
    # each a map variant -> weight summing to 0 (file: [{cc: 1, baseline: -1}])
    contrasts: tuple[tuple[tuple[str, float], ...], ...] = key(
        default=(), written=list[dict[str, Any]], read=lambda weights: tuple(map(pairs, weights)))
    # interaction: (a, b) per scene, in the order of ``scenes`` (file: [[stride1, stride5], [stride2, stride4]])
    pairs: tuple[tuple[str, str], ...] = key(default=(), written=list[list[str]],
                                             read=lambda rows: tuple(tuple(r) for r in rows))
    # decoupled / dissociated: the variants whose pairs the existential search tries (default: every
    # variant of the study); pins a claim's scope when arms are added to its study later
    among: tuple[str, ...] = ()
    requires: tuple[Requires, ...] = ()  # all must be present (file: a list of {metric, min} / {metric, above})
    needs: str = ""  # real data the claim needs; "not tested" rows say so
    withdrawn: str = ""  # why it no longer counts (its result stays in view)
    history: tuple[str, ...] = ()  # what changed since it was first registered, and why
    plan: PlanSpec | None = None  # a mean claim's own sequential plan keys (over the profile's ``sequential:``)
    unit: Unit = Unit.instance  # a mean claim's unit over several scene instances (``Unit``)
    sesoi: float = derived(0.1)  # from the metric registry (the loader fills it in)
    sesoi_source: str = derived("")

    def arms(self) -> tuple[str, ...]:
        """Every variant the claim compares, in order of first mention."""
        named = [self.a, self.b, *(v for w in self.contrasts for v, _ in w), *(v for p in self.pairs for v in p),
                 *self.among]
        return tuple(dict.fromkeys(v for v in named if v))


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
    # the files of the runs' diagnostics/ artifacts the report copies (fnmatch patterns); none when empty
    diagnostics: tuple[str, ...] = ()
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
