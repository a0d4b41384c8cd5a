"""Runs until decided, driven from a study's runs (issue 57; docs/sequential.md).

``design(study, profile, register)`` is a study's sequential design under one profile: every
counted mean claim (``verdicts.counts`` at the claim's level: not withdrawn, not evidence or a
replaced claim in the paper register) whose arms and scenes the profile runs, with its plan —
the profile's ``sequential:`` block, the claim's own ``plan:`` over it (``plan_of``) — in
families by ``group``, as ``verdicts.decide`` forms them.

``decide(design, runs)`` then replays each family's rounds from the runs frame
(``report.results.runs_frame``), holding no state of its own: round k = 0, 1, 2, … reads every
open claim at look ``schedule[min(k, last)]`` (as ``sequential.simulate`` does) with one
``sequential.decide_family`` call, and stops at the first round at which some open claim lacks
the runs that look needs: that claim continues and needs that many runs per arm. So a decision
is a function of the runs alone — recomputing it from a ``runs.csv`` gives the same answer — and
runs beyond a look's count wait for that look.

A claim's runs enter in seed order: seed ``base_seed`` on each of the claim's scenes (in the
claim's order), then the next seed (``SeqClaim.cells``) — or, when the profile draws its scenes
as several instances and the claim takes the instance as its unit (``spec.instances``), in
instance order: fresh instance 1 of each of its scenes at seed ``base_seed``, then instance 2, …
(one run per instance and arm; instance 0, the pilot, never enters), so that a look reads
instances and the claim's cap is a number of instances, at most those the profile draws. A
look at n runs per arm (pairs for a paired claim) reads the first n cells, and a cell that has
not finished holds back every cell after it, so no run is ever skipped. ``next_round`` is the
``study run`` selection that adds the next round of every continuing claim. The command and its printing: ``harness.cli.decide``.

    d = design(load_study("ablation"), "quick", load_register())
    for family in decide(d, collect("ablation", selection(d)).df): ...
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ftgspp.errors import InputError
from harness.analysis import claim_tests as C, sequential as Q, stats, verdicts as V
from harness.spec.instances import PILOT, instance_name, takes_instances
from harness.spec.paper_register import Register
from harness.spec.runs import Selection
from harness.spec.study_schema import ClaimSpec, Comparison, Pairing, ProfileSpec, StudySpec

PLAN_KEYS = ("first", "per_round", "rounds", "cap_runs", "cap_cpu_hours")
SPENDING_NAMES = {"obf": "O'Brien–Fleming", "pocock": "Pocock"}


class DesignError(InputError):
    """A sequential design the study file cannot run (an impossible plan, a cap above the instances
    drawn), as against a study without one."""


@dataclass(frozen=True)
class SeqClaim:
    """A counted mean claim run until decided under one profile."""

    spec: ClaimSpec
    plan: Q.Plan
    base_seed: int
    fresh: int = 0  # fresh instances of each of its scenes (the instance its unit); 0: seeds of the scene

    @property
    def paired(self) -> bool:
        return bool(self.spec.b) and self.spec.pair == Pairing.seed

    @property
    def unit(self) -> str:
        """What the plan counts: pairs, runs per arm (Welch) or runs (one sample); of instances
        when the instance is the unit."""
        if self.fresh:
            return "paired instances" if self.paired else "instances per arm" if self.spec.b else "instances"
        return "pairs" if self.paired else "runs per arm" if self.spec.b else "runs"

    def seeds(self, n: int) -> int:
        """Seeds that give each arm ``n`` runs over the claim's scenes (one per instance)."""
        return 1 if self.fresh else math.ceil(n / len(self.spec.scenes))

    def cells(self, n: int) -> list[tuple[str, int]]:
        """The first ``n`` (scene, seed) cells of an arm, in the order its runs enter (module docstring)."""
        if self.fresh:
            return [(instance_name(s, i), self.base_seed) for i in range(PILOT + 1, PILOT + 1 + self.fresh)
                    for s in self.spec.scenes][:n]
        return [(s, self.base_seed + r) for r in range(self.seeds(n)) for s in self.spec.scenes][:n]

    def scenes(self, n: int) -> tuple[str, ...]:
        """The scenes (instances) a look at ``n`` reads: the claim's own, or its first fresh instances."""
        return tuple(dict.fromkeys(s for s, _ in self.cells(n))) if self.fresh else self.spec.scenes


@dataclass(frozen=True)
class Design:
    """A study's sequential design under one profile (module docstring)."""

    study: StudySpec
    profile: ProfileSpec
    families: dict[str, list[SeqClaim]]
    left_out: tuple[tuple[str, str], ...]  # (claim id, why it is not run until decided here)
    # per family: (claims that count in the group over every study file, the α its claims here hold)
    shares: dict[str, tuple[int, float]] = dataclasses.field(default_factory=dict)

    def alpha(self, family: str) -> float:
        """The α this study's claims of ``family`` are decided at (``group_shares``)."""
        return self.shares.get(family, (0, stats.ALPHA))[1]

    @property
    def claims(self) -> list[SeqClaim]:
        return [c for claims in self.families.values() for c in claims]

    @property
    def hours_per_run(self) -> float | None:
        """CPU hours of one run at the profile's ``run_seconds`` (None: not given)."""
        return self.profile.run_seconds / 3600 if self.profile.run_seconds > 0 else None

    @property
    def study_cap(self) -> float | None:
        """The CPU hours every round together may take (the profile's ``study_cap_cpu_hours``)."""
        return self.profile.sequential.study_cap_cpu_hours if self.profile.sequential else None

    def hours(self, runs: int) -> float:
        """CPU hours of ``runs`` runs (NaN when the profile gives no ``run_seconds``)."""
        return runs * self.hours_per_run if self.hours_per_run else math.nan

    def worst_case(self) -> int:
        """Runs of every claim at its cap, a run that several claims share counted once."""
        return len({(v, s, seed) for c in self.claims for v in c.spec.arms() for s, seed in c.cells(c.plan.n_max)})

    def rounds(self) -> int:
        """The most rounds any family can take (its longest schedule)."""
        return max(len(c.plan.schedule()) for c in self.claims)


def plan_of(claim: ClaimSpec, profile: ProfileSpec) -> Q.Plan:
    """The claim's ``sequential.Plan`` under ``profile``: its ``plan:`` keys over the profile's
    ``sequential:`` ones, the library's defaults for keys neither sets; CPU hours per run from the
    profile's ``run_seconds``; one arm for a one-sample claim."""
    keys: dict = {}
    for source in (profile.sequential, claim.plan):
        keys |= {k: getattr(source, k) for k in PLAN_KEYS if source is not None and getattr(source, k) is not None}
    hours = profile.run_seconds / 3600 if profile.run_seconds > 0 else None
    plan = Q.Plan(**keys, cpu_hours_per_run=hours, arms=2 if claim.b else 1)
    plan.schedule()  # raises when the caps leave fewer than 2 runs an arm
    return plan


def fresh_instances(claim: ClaimSpec, profile: ProfileSpec) -> int:
    """Fresh instances (1, 2, …) the profile draws of each of the claim's scenes, the fewest of
    any, when the claim takes the instance as its unit (``spec.instances.takes_instances``); 0
    otherwise (its runs are seeds of the scenes as written)."""
    if not takes_instances(claim):
        return 0
    drawn = [sum(1 for s in profile.scenes if s.base == name and s.instance > PILOT) for name in claim.scenes]
    return min(drawn, default=0)


def _why_not(study: StudySpec, profile: ProfileSpec, claim: ClaimSpec, register: Register) -> str:
    """Why a counted mean claim is not run until decided under ``profile`` ("" when it is)."""
    if not counts_in_group(study.name, claim, register):
        return "not counted (withdrawn, evidence or replaced)"
    scenes = {s.name: s for s in profile.scenes}
    if any(v not in profile.variants for v in claim.arms()) or any(s not in scenes for s in claim.scenes):
        return f"the {profile.name} profile does not run its arms on its scenes"
    if any(scenes[s].variants and not set(claim.arms()) <= set(scenes[s].variants) for s in claim.scenes):
        return f"the {profile.name} profile does not run every arm on each of its scenes"
    return ""


def counts_in_group(study: str, claim: ClaimSpec, register: Register) -> bool:
    """Does the claim enter its group's family whenever it is tested (``verdicts.counts`` before
    the data: not withdrawn; a paper claim only when it decides its statement or is in none)?"""
    found = register.role(study, claim.id)
    role = found[1] if found else ""
    if claim.withdrawn or role in (V.AS_EVIDENCE, V.REPLACED):
        return False
    return str(claim.group) != "paper" or role in ("", V.DECIDES)


def group_shares(study: StudySpec, families: dict[str, list[SeqClaim]], register: Register,
                 others: dict[str, StudySpec]) -> dict[str, tuple[int, float]]:
    """Per family: (its claims that count over every study — this one and ``others`` — and the α
    this study's sequential claims hold: α × theirs / all). A report's family is a group over
    every study, decided by one fixed-n Holm; the sequential claims take their share of its α
    (a Bonferroni split between the parts: the group's error is at most the sum of the parts'),
    so deciding them never borrows α the rest of the group holds. Counted from the study files
    and the paper register alone, before any run."""
    out = {}
    for group, claims in families.items():
        total = sum(counts_in_group(name, c, register) for name, spec in {**others, study.name: study}.items()
                    for c in spec.claims if str(c.group) == group)
        out[group] = (total, stats.ALPHA * len(claims) / max(total, len(claims)))
    return out


def design(study: StudySpec, profile: str, register: Register,
           others: Callable[[], dict[str, StudySpec]] | None = None) -> Design:
    """The study's sequential design under ``profile``; ``InputError`` when it has none (no
    ``sequential:`` block, no mean claim this profile runs) or a plan is impossible. ``others``
    gives the other study files (for each family's share of its group's α, ``group_shares``);
    it is called after this study's own checks."""
    prof = study.profile(profile)
    where = f"study decide {study.name} --profile {prof.name}"
    means = [c for c in study.claims if c.test == Comparison.mean]
    if not means:
        raise InputError(where, "the study has no mean claims (test: mean): nothing to run until decided")
    if prof.sequential is None:
        raise InputError(where, f"no sequential plan: add `sequential:` to profiles.{prof.name} of"
                                f" {study.path or study.name} (docs/sequential.md)")
    families: dict[str, list[SeqClaim]] = {}
    left_out = []
    for c in study.claims:
        why = _why_not(study, prof, c, register)
        if c.test != Comparison.mean:
            counted = counts_in_group(study.name, c, register)
            a = "an" if str(c.test)[0] in "aeiou" else "a"
            left_out.append((c.id, f"{a} {c.test} claim: the report decides it at fixed n" if counted else why))
            continue
        if why:
            left_out.append((c.id, why))
            continue
        try:
            claim = SeqClaim(c, plan_of(c, prof), study.base_seed, fresh_instances(c, prof))
        except ValueError as err:
            raise DesignError(f"{where}: claim {c.id}", f"impossible plan ({err})") from None
        if claim.fresh and claim.plan.n_max > claim.fresh * len(c.scenes):
            raise DesignError(f"{where}: claim {c.id}", f"its cap is {claim.plan.n_max} {claim.unit}, but the"
                                                       f" {prof.name} profile draws {claim.fresh} fresh instances of"
                                                       f" each of its {len(c.scenes)} scene(s): raise `instances:`"
                                                       " or lower the cap")
        families.setdefault(str(c.group), []).append(claim)
    if not families:
        raise InputError(where, f"none of its mean claims is counted and run by the {prof.name} profile")
    # the other study files are read only now, so that this study's own errors come first
    rest = {k: v for k, v in (others() if others else {}).items() if k != study.name}
    shares = group_shares(study, families, register, rest)
    return Design(study, prof, families, tuple((i, w) for i, w in left_out if w), shares)


def selection(d: Design) -> Selection:
    """The runs every sequential claim may use: its arms on its scenes, up to the most seeds a cap needs."""
    seeds = max(c.seeds(c.plan.n_max) for c in d.claims)
    variants = list(dict.fromkeys(v for c in d.claims for v in c.spec.arms()))
    scenes = list(dict.fromkeys(s for c in d.claims for s in c.scenes(c.plan.n_max)))
    return Selection(profile=d.profile.name, seeds=seeds, variants=variants, scenes=scenes)


# --------------------------------------------------------------------------- runs and replay


def _prefix(values: pd.Series, cells: list[tuple[str, int]]) -> np.ndarray:
    """``values`` (indexed by scene, seed) over ``cells`` in order, up to the first cell without one."""
    found = {(str(s), int(seed)): float(v) for (s, seed), v in values.items()} if len(values) else {}
    out = []
    for cell in cells:
        if cell not in found:
            break
        out.append(found[cell])
    return np.array(out, dtype=float)


def observed(df: pd.DataFrame, c: SeqClaim) -> Q.Claim:
    """The claim's runs so far, up to its cap, as ``claim_compare.compare`` tests it: the paired
    differences a − b by (scene, seed) (``pair: seed``), each arm's runs (Welch, ``pair: none``)
    or arm a's runs (one sample); each in the order runs enter (``SeqClaim.cells``)."""
    spec, cells = c.spec, c.cells(c.plan.n_max)
    if c.paired:
        arms = [C.paired_differences(df, spec, spec.scenes)]
    else:
        arms = [C.wide(df, spec.metric, [v], spec.scenes)[v] for v in (spec.a, spec.b) if v]
    a, *b = [_prefix(values, cells) for values in arms]
    return Q.Claim(spec.id, a, b[0] if b else None, spec.sesoi, paired=not b, expect=str(spec.expect), plan=c.plan)


def replay(claims: list[Q.Claim], alpha: float = stats.ALPHA, spending: str = "obf"
           ) -> tuple[list[Q.Decision | None], list[int], int, dict]:
    """One family's rounds replayed from its claims' runs (module docstring): (each claim's
    latest decision, None before the first round; the runs per arm each continuing claim's next
    look needs, 0 for the others; the rounds decided; ``decide_family``'s state after them)."""
    schedules = [c.plan.schedule() for c in claims]
    decisions: list[Q.Decision | None] = [None] * len(claims)
    state: dict = {}
    for k in range(max(map(len, schedules))):
        looks = [s[min(k, len(s) - 1)] for s in schedules]
        open_ = [not state.get(c.name, {}).get("rejected") and k < len(s) for c, s in zip(claims, schedules)]
        if any(o and c.n < n for o, c, n in zip(open_, claims, looks)):
            return decisions, [n if o else 0 for o, n in zip(open_, looks)], k, state
        now = [dataclasses.replace(c, a=c.a[:n], b=None if c.b is None else c.b[:n]) for c, n in zip(claims, looks)]
        decisions, state = Q.decide_family(now, state or None, alpha, spending)
    return decisions, [0] * len(claims), max(map(len, schedules)), state


@dataclass(frozen=True)
class Outcome:
    """One claim after its family's replay."""

    claim: SeqClaim
    runs: Q.Claim  # its runs so far, in the order they enter
    decision: Q.Decision | None  # the latest round's; None before the first
    needs: int  # runs per arm its next look needs; 0 when decided or at its cap

    @property
    def status(self) -> str:
        return Q.CONTINUE if self.needs or self.decision is None else self.decision.status


@dataclass(frozen=True)
class FamilyReplay:
    """A family's claims after the replay of its rounds."""

    name: str
    outcomes: list[Outcome]
    rounds: int  # rounds decided so far
    state: dict  # ``decide_family``'s, after the last of them


def decide(d: Design, df: pd.DataFrame, spending: str = "obf") -> list[FamilyReplay]:
    """Every family of the design replayed on the runs frame ``df``, each from its own claims'
    runs only, at its share of the group's α (``Design.alpha``)."""
    out = []
    for name, claims in d.families.items():
        runs = [observed(df, c) for c in claims]
        decisions, needs, rounds, state = replay(runs, d.alpha(name), spending)
        out.append(FamilyReplay(name, [Outcome(*x) for x in zip(claims, runs, decisions, needs)], rounds, state))
    return out


# --------------------------------------------------------------------------- the next round


@dataclass(frozen=True)
class Round:
    """The ``study run`` selection that adds the next round of every continuing claim."""

    variants: tuple[str, ...]
    scenes: tuple[str, ...]
    seeds: int
    runs: int  # runs it launches: the selection's runs that have not finished
    own: int  # of them, those the continuing claims' next looks read


def finished_runs(df: pd.DataFrame) -> set[tuple[str, str, int]]:
    """(variant, scene, seed) of every finished run of ``df``."""
    ok = df[df.status == "FINISHED"]
    return {(str(v), str(s), int(seed)) for v, s, seed in zip(ok.variant, ok.scene, ok.seed)}


def missing_cells(o: Outcome, done: set[tuple[str, str, int]]) -> list[tuple[str, str, int]]:
    """The runs a continuing claim's next look still needs: its arms over its first ``needs`` cells."""
    return [(v, s, seed) for s, seed in o.claim.cells(o.needs) for v in o.claim.spec.arms() if (v, s, seed) not in done]


def next_round(d: Design, families: list[FamilyReplay], df: pd.DataFrame) -> Round | None:
    """The next round (None when no claim continues): the arms and scenes of the continuing
    claims that lack runs (a claim that has its next look's runs waits for its family), the most
    seeds one of their next looks needs. One ``study run`` runs every variant on every scene of
    it: ``runs`` counts those not yet finished, ``own`` those a next look reads."""
    going = [o for f in families for o in f.outcomes if o.needs]
    if not going:
        return None
    done = finished_runs(df)
    going = [o for o in going if missing_cells(o, done)] or going
    variants = tuple(dict.fromkeys(v for o in going for v in o.claim.spec.arms()))
    # a claim on instances asks for the instances it lacks; a claim on seeds for its scenes up to ``seeds``
    scenes = tuple(dict.fromkeys(s for o in going for s in (
        [cell[1] for cell in missing_cells(o, done)] or o.claim.scenes(o.needs) if o.claim.fresh
        else o.claim.spec.scenes)))
    seeds = max(o.claim.seeds(o.needs) for o in going)
    grid = df[df.variant.isin(variants) & df.scene.isin(scenes) & (df.seed < d.study.base_seed + seeds)]
    runs = int((grid.status != "FINISHED").sum())
    own = len({cell for o in going for cell in missing_cells(o, done)})
    return Round(variants, scenes, seeds, runs, own)


def spent(d: Design, df: pd.DataFrame) -> int:
    """Finished runs of the design's arms on its scenes (what its CPU cap counts)."""
    sel = selection(d)
    return int(((df.status == "FINISHED") & df.variant.isin(sel.variants) & df.scene.isin(sel.scenes)).sum())
