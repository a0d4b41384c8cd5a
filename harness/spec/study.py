"""The study file as data: the dataclasses ``spec.files`` fills from ``studies/<name>.yaml``.

A study file is plain data (see ``studies/secret5.yaml``): a question, named variants
(lists of Hydra override strings, one of them the baseline), per-profile scenes, seed
counts, overrides, expected runtime and the exact command, plus what the report shows.
Scenes are either synthetic (``synth: {preset, seed, layout, n_cameras, color_shift, ...}``:
arguments of ``ftgspp.data.synthetic.generate``, generated on demand into
``data/synth/<name>``) or given by overrides (``data.path=${oc.env:DYNERF_ROOT}/...``). A
study may list ``claims:`` (the paper's statements as data, see ``ClaimSpec``) and
``variance_components:`` (``VarianceSpec``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ftgspp.errors import InputError

PROFILES = ("quick", "paper", "smoke")
TINY_SYNTH = {"width": 64, "height": 48, "n_frames": 6, "n_cameras": 5}
SYNTH_ROOT = Path("data/synth")
# the smoke scenes are generated at 64x48 already: train them at full resolution
SMOKE_OVERRIDES = ("profile=smoke", "data.downsample=1")
JOBS_SPEEDUP = 1.36  # throughput of 2 parallel runs over 1 on 2 cores (BENCHMARKS.md); more: no more


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


TABLE_LAYOUTS = ("variants_x_scenes", "metrics_x_scenes", "variants_x_metrics")
PLOTS = ("strip", "speed_accuracy", "stability")
NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")
# claims: test kinds, the expectations each allows, and the metrics a claim may name
DIRECTIONS = ("higher", "lower", "not_higher", "not_lower")
CLAIM_TESTS = {"mean": DIRECTIONS, "variance": DIRECTIONS, "interaction": DIRECTIONS, "contrast": ("higher", "lower"),
               "decoupled": ("exists",)}
CLAIM_GROUPS = {"paper": "the paper's method claims", "extension": "this project's own extensions",
                "convention": "metric conventions"}


@dataclass(frozen=True)
class StudyScene:
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
    scenes: tuple[StudyScene, ...]
    variants: dict[str, tuple[str, ...]]
    expected_runtime: str = ""
    command: str = ""
    baseline: str = ""
    jobs: int = 1  # parallel runs when `study run` is given no --jobs
    run_seconds: float = 0.0  # wall seconds per run, one at a time, on ``machine`` (0: unknown)
    machine: str = ""

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

    layout: str = "variants_x_scenes"
    metrics: tuple[str, ...] = ("psnr",)  # fnmatch patterns (e.g. lpips_*)
    unranked: tuple[str, ...] = ()  # variants shown but never ranked (hardware controls, not methods)


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
    """The paper's statement (paraphrased), where it makes it, and its numbers per dataset."""

    statement: str
    source: str
    rows: tuple[PaperRow, ...] = ()


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
    (equivalent counts as reproduced), ``exists`` (decoupled).
    ``sesoi``: the smallest effect of interest in the effect's units, fixed in the study file
    before the runs (``sesoi_source`` says where it comes from); ``group`` names the family
    the claim is corrected in (``paper``: the paper's method claims; ``extension``: this
    project's own; ``convention``: metric conventions). ``requires``: a metric whose median
    over the claim's runs must reach a value for the claim's mechanism to be present on the
    scene (else "not exercised").
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
    sesoi: float = 0.1
    sesoi_source: str = ""
    group: str = "paper"
    paper: PaperClaim | None = None
    contrasts: tuple[tuple[tuple[str, float], ...], ...] = ()
    requires: tuple[str, float] | None = None
    needs: str = ""  # real data the claim needs; "not tested" rows say so


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
class VarianceSpec:
    """Which variants isolate each source of run-to-run spread (``harness.variance``)."""

    metric: str
    optimisation: str  # fixed initialisation, the seed varies the optimisation only
    initialisation: str  # the initialisation is re-drawn per seed too
    hardware: tuple[str, ...]  # same seed and initialisation, another CPU kernel dispatch each


