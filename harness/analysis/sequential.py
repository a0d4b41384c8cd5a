"""Runs until decided: a group-sequential design that adds seeds, round by round, only to the
claims of a family that are still inconclusive, and keeps the family's error rate (issue 57).

The rule: Lan–DeMets α-spending (O'Brien–Fleming-type by default, Pocock-type on request) per
hypothesis, one Holm-type recycling over the union of a family's difference and equivalence
hypotheses (Maurer & Bretz 2013), boundaries calibrated for the t statistic. Why this rule and
not anytime-valid confidence sequences, and its error guarantee: docs/sequential.md. In brief:

- rounds not fixed in advance: a spending function needs only each claim's cap (its maximum
  runs, fixed in its ``Plan`` before the first round); how many looks happen and when is free,
  and a claim may stop early (decided, or out of budget) — stopping early spends less, never more;
- equivalence: TOST's two one-sided tests each meet a one-sided boundary at the hypothesis' α
  share (an intersection–union test needs no split); a difference hypothesis meets two-sided
  boundaries (half its share each side); an "≈" claim's minimal-effect test too;
- small n, t not z: z boundaries read as t p-values ("the significance level approach",
  Jennison & Turnbull 1999 §3.4) overshoot at 3 pairs (0.055–0.061 for 0.05, measured), so each
  look's level is calibrated on 2^18 simulated null paths of the t statistic itself (exact for
  paired and one-sample t, whose null law is free of the variance; Welch is read conservatively,
  ``pvalues``). Checked against the published z boundaries at large n and by simulation at n = 3
  in tests/harness/test_sequential.py;
- confidence sequences valid at any stopping time (Howard et al. 2021) pay for that at 3–15
  runs: Robbins' normal mixture tuned for n = 10 is 1.16σ wide each side at n = 10 with σ known,
  the t interval 0.72σ; and the installable ones need a known variance bound or bounded data
  (``confseq``), or Python ≥ 3.12 and a GPL licence with an AI-training clause (``expectation``).
  ``gsdesign`` (0.1.5) ships only gsDesign's z-scale integration primitives, no t boundaries: no
  dependency was added; scipy's t law and numpy's generator do the calibration.

Use: ``decide_study({family: [Claim, ...]}, state)`` after each round returns, per claim, a
``Decision`` (decided: which hypothesis was rejected / continue: how many runs next / stop at
cap: the runs a fixed design would need at its α share) and the state to pass back in next time
(a plain JSON-able dict). Each family is decided from its own claims only. ``simulate`` runs the
whole procedure on simulated families (vectorised, for the error-rate checks and for planning).
Scene instances as the unit (pseudo-replication): ``harness.analysis.instance_unit``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy import stats as sps

from harness.analysis import stats

SPENDING = ("obf", "pocock", "none")  # "none": every look at the fixed-n level (naive peeking; a contrast)
HYPOTHESES = ("difference", "equivalence")
PATHS = 2 ** 18  # null paths of the t statistic; a level errs by ~1/√(PATHS·share): 1% at 0.05, 3% at 0.005
SEED = 20_261_128
DECIDED, CONTINUE, AT_CAP = "decided", "continue", "stop at cap"


def spent(t: float, alpha: float, spending: str = "obf") -> float:
    """Cumulative one-sided α spent by information fraction ``t`` ∈ (0, 1] (Lan & DeMets 1983):
    O'Brien–Fleming-type 2 − 2Φ(z_{1−α/2}/√t), Pocock-type α·ln(1 + (e − 1)t)."""
    t = min(1.0, t)
    if spending == "obf":
        return float(2.0 * sps.norm.sf(sps.norm.isf(alpha / 2) / math.sqrt(t)))
    if spending == "pocock":
        return float(alpha * math.log1p((math.e - 1.0) * t))
    raise ValueError(f"unknown spending function {spending!r} (one of {SPENDING[:2]})")


@lru_cache(maxsize=32)  # 6 MB an entry
def _paths(looks: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PATHS null paths of the one-sample t statistic (standard normal runs, seed SEED) at runs
    ``looks``: (sum of the runs, sum of squares about their mean, upper one-sided p at the last
    look), each [PATHS]. A look adds a block of runs through its sufficient statistics (the
    block's mean and its χ² sum of squares), so a schedule's paths extend its prefix's."""
    n = looks[-1]
    if len(looks) == 1:
        rng, total, ss, before = np.random.default_rng(SEED), np.zeros(PATHS), np.zeros(PATHS), 0
    else:
        total, ss, _ = _paths(looks[:-1])
        before = looks[-2]
        rng = np.random.default_rng([SEED, *looks[:-1]])
    block = n - before
    mean = rng.normal(0.0, 1.0 / math.sqrt(block), PATHS)
    within = rng.chisquare(block - 1, PATHS) if block > 1 else np.zeros(PATHS)
    ss = ss + within + (before * block / n) * (total / max(before, 1) - mean) ** 2
    total = total + block * mean
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (total / n) / np.sqrt(ss / (n - 1) / n)
    return total, ss, sps.t.sf(t, n - 1)


def _null_p(looks: tuple[int, ...], two_sided: bool) -> np.ndarray:
    """The null paths' p at the last of ``looks`` (two-sided: twice the smaller tail)."""
    p = _paths(looks)[2]
    return 2 * np.minimum(p, 1 - p) if two_sided else p


@lru_cache(maxsize=65_536)
def _calibrated(looks: tuple[int, ...], n_max: int, alpha: float, two_sided: bool, spending: str
                ) -> tuple[float, ...]:
    """The nominal p-level of every look: each is the order statistic of the still-running null
    paths' p that stops as many paths as the spending function allows by then (never more), so
    the test spends α as planned on the t statistic itself, at its own degrees of freedom."""
    before = _calibrated(looks[:-1], n_max, alpha, two_sided, spending) if len(looks) > 1 else ()
    alive = np.ones(PATHS, bool)
    for k, level in enumerate(before):  # the paths the earlier looks stopped
        alive &= _null_p(looks[:k + 1], two_sided) > level
    p = _null_p(looks, two_sided)[alive]
    allowed = int(math.floor(PATHS * spent(looks[-1] / n_max, alpha, spending) + 1e-9)) - (PATHS - len(p))
    if allowed < 1:
        return (*before, 0.0)
    return (*before, float(np.partition(p, allowed - 1)[allowed - 1]) if allowed <= len(p) else 1.0)


def nominal_levels(looks: tuple[int, ...], n_max: int, alpha: float, two_sided: bool = False,
                   spending: str = "obf") -> np.ndarray:
    """The nominal p-level of each look of a group-sequential t-test at ``alpha`` with looks at
    ``looks`` runs (increasing, at most ``n_max``, the information fraction being runs/n_max):
    a look rejects when its t-test's p (one-sided, or two-sided when ``two_sided``) is at most
    its level. Calibrated on PATHS simulated null paths of the t statistic (exact for a paired
    or one-sample t: its null law is free of the variance; a Welch test is read with the same
    levels, those of its heaviest-tailed limit). ``spending="none"``: ``alpha`` at every look."""
    looks = tuple(int(n) for n in looks)
    if looks[0] < 2 or looks[-1] > n_max or any(b <= a for a, b in zip(looks, looks[1:])):
        raise ValueError(f"looks must increase from 2 runs to at most {n_max}: {looks}")
    if spending == "none":
        return np.full(len(looks), alpha)
    return np.array(_calibrated(looks, n_max, round(alpha, 15), two_sided, spending))


@dataclass(frozen=True)
class Plan:
    """One claim's sequential plan, fixed before its first round. Counts are runs per arm (pairs
    for a paired claim): ``first`` at the first look, then ``per_round`` more a round, at most
    ``rounds`` looks; the caps (all arms together) cut the schedule short."""

    first: int = 3
    per_round: int = 2
    rounds: int = 5
    cap_runs: int | None = None  # runs of the claim, every arm counted
    cap_cpu_hours: float | None = None
    cpu_hours_per_run: float | None = None
    arms: int = 2  # 1 for a one-sample claim

    def __post_init__(self) -> None:
        if self.first < 2 or self.per_round < 1 or self.rounds < 1:
            raise ValueError(f"a plan needs first >= 2, per_round >= 1, rounds >= 1: {self}")

    @property
    def n_max(self) -> int:
        """Runs per arm at the last look: the schedule's, or fewer when a cap says so."""
        n = self.first + (self.rounds - 1) * self.per_round
        if self.cap_runs is not None:
            n = min(n, self.cap_runs // self.arms)
        if self.cap_cpu_hours is not None and self.cpu_hours_per_run:
            n = min(n, int(self.cap_cpu_hours // (self.cpu_hours_per_run * self.arms)))
        if n < 2:
            raise ValueError(f"the caps leave {n} runs per arm (a t-test needs 2): {self}")
        return n

    def schedule(self) -> tuple[int, ...]:
        """Runs per arm at each planned look."""
        looks = [n for n in range(self.first, self.n_max + 1, self.per_round)]
        return tuple(looks if looks and looks[-1] == self.n_max else [*looks, self.n_max])


@dataclass(frozen=True, eq=False)
class Claim:
    """A mean claim of a family and its runs so far, in seed order (``a[i]`` with ``b[i]`` when
    ``paired``; ``b`` None: a one-sample claim). ``expect`` as in ``ClaimSpec`` ("equivalent":
    the difference slot is the minimal-effect test); ``alternative``: the difference test's."""

    name: str
    a: np.ndarray  # [n_a]
    b: np.ndarray | None  # [n_b]
    sesoi: float
    paired: bool = True
    expect: str = "higher"
    alternative: str = "two-sided"
    plan: Plan = field(default_factory=Plan)

    @property
    def n(self) -> int:
        return len(self.a) if self.b is None else min(len(self.a), len(self.b))


def _two_sided(c: Claim) -> bool:
    """Is the claim's difference slot two-sided (a two-sided t, or the minimal-effect test)?"""
    return c.alternative == "two-sided" or c.expect == "equivalent"


def pvalues(a: np.ndarray, b: np.ndarray | None, sesoi: float, paired: bool = True, expect: str = "higher",
            alternative: str = "two-sided") -> tuple[np.ndarray, np.ndarray]:
    """(p of the difference test, p of the equivalence test) over the last axis of ``a`` [..., n]
    and ``b`` — many experiments at once. Paired and one-sample claims: exactly
    ``claim_tests.compare_means``' ``p`` (``p_outside`` for "≈") and ``p_tost`` (scipy's t-tests,
    vectorised). Unpaired claims: Welch's t read at min(n_a, n_b) − 1 degrees of freedom, never
    more than Welch–Satterthwaite's, so each p below ½ is at least ``compare_means``' — the limit where
    one arm's variance dominates, the law ``nominal_levels`` calibrates (Welch's own degrees of
    freedom change from look to look with the variances seen and overshoot α by ~7% at n = 3)."""
    if b is None or paired:
        d = a if b is None else a - b
        def one(shift: float, side: str) -> np.ndarray:
            return sps.ttest_1samp(d, shift, axis=-1, alternative=side).pvalue
    else:
        dof = min(a.shape[-1], b.shape[-1]) - 1
        def one(shift: float, side: str) -> np.ndarray:  # Welch's statistic for a − b against ``shift``
            t = sps.ttest_ind(a - shift, b, axis=-1, equal_var=False).statistic
            return {"greater": sps.t.sf(t, dof), "less": sps.t.cdf(t, dof)}.get(side, 2 * sps.t.sf(np.abs(t), dof))
    p_tost = np.maximum(one(-sesoi, "greater"), one(sesoi, "less"))
    if expect == "equivalent":  # "≈": the effect lies outside ±SESOI (stats.minimal_effect_p)
        return np.minimum(1.0, 2 * np.minimum(one(sesoi, "greater"), one(-sesoi, "less"))), p_tost
    return one(0.0, alternative), p_tost


def level_table(looks: tuple[int, ...], n_max: int, m: int, alpha: float, spending: str, two_sided: bool
                ) -> np.ndarray:
    """[2, m]: the nominal levels, on the p scale of ``pvalues``, of a claim's (difference,
    equivalence) hypotheses at its latest look when the family has j = 1..m hypotheses open
    (Holm: each holds α/j); each of TOST's two one-sided tests meets the one-sided level."""
    table = np.empty((2, m))
    for j in range(1, m + 1):
        table[0, j - 1] = nominal_levels(looks, n_max, alpha / j, two_sided, spending)[-1]
        table[1, j - 1] = nominal_levels(looks, n_max, alpha / j, False, spending)[-1]
    return table


def holm_look(p: np.ndarray, levels: np.ndarray, rejected: np.ndarray, testable: np.ndarray) -> np.ndarray:
    """One look of the family's sequentially rejective procedure, over R experiments at once.

    p [C, 2, R]: each claim's (difference, equivalence) p at its latest look; levels [C, 2, m]
    (``level_table``); rejected [C, 2, R] before this look; testable [C, R]: the claim is still
    open. A hypothesis is rejected when its p is at most its level for the number of hypotheses
    still open; each rejection raises the others' shares and the look is read again. A claim
    with a rejection is closed: its other hypothesis keeps its share, untested (Maurer & Bretz
    2013: a Holm graph over group-sequential tests). Returns the new ``rejected``."""
    rejected, testable = rejected.copy(), testable.copy()
    m = levels.shape[-1]
    while True:
        open_ = m - rejected.sum(axis=(0, 1))  # [R]
        level = np.take_along_axis(levels[:, :, None, :], np.maximum(open_, 1)[None, None, :, None] - 1,
                                   axis=-1)[..., 0]  # [C, 2, R]
        new = testable[:, None, :] & ~rejected & (p <= level)
        if not new.any():
            return rejected
        rejected |= new
        testable &= ~new.any(axis=1)


@dataclass(frozen=True)
class Decision:
    """What one claim does next."""

    claim: str
    status: str  # DECIDED, CONTINUE or AT_CAP
    rejected: tuple[str, ...]  # of HYPOTHESES
    verdict: str  # verdicts.verdict of the rejections (inconclusive while none)
    n: int  # runs per arm (pairs) at the latest look
    look: int  # 1-based
    share: float  # the α each open hypothesis holds now (α / open hypotheses)
    levels: tuple[float, float]  # the nominal levels (difference, equivalence) the look met
    p: tuple[float, float]
    runs_next: int = 0  # runs (every arm) the next round adds
    runs_needed: float = math.nan  # at the cap: runs per arm a fixed design needs at ``share`` (80% power)


def decide_family(claims: list[Claim], state: dict | None = None, alpha: float = stats.ALPHA,
                  spending: str = "obf") -> tuple[list[Decision], dict]:
    """Every counted claim of ONE family at the current round: the latest look of each open
    claim (the runs it has, up to its cap), one ``holm_look`` over the family's 2·len(claims)
    hypotheses. ``state`` (from the previous call; None the first time) holds each claim's looks
    and rejections: a decided claim stays at the look that decided it, a claim at its cap is read
    again at its last look when others' rejections raise its share. Returns the decisions and
    the new state."""
    from harness.analysis import verdicts

    state = {c.name: dict(looks=[], rejected=[]) for c in claims} | {
        k: dict(looks=list(v["looks"]), rejected=list(v["rejected"])) for k, v in (state or {}).items()}
    m = 2 * len(claims)
    p = np.ones((len(claims), 2, 1))
    levels = np.zeros((len(claims), 2, m))
    rejected = np.zeros((len(claims), 2, 1), bool)
    for i, c in enumerate(claims):
        s, n_max = state[c.name], c.plan.n_max
        n = min(c.n, n_max)
        if not s["rejected"] and n >= 2 and (not s["looks"] or n > s["looks"][-1]):
            s["looks"].append(n)
        rejected[i, :, 0] = [h in s["rejected"] for h in HYPOTHESES]
        if not s["looks"]:
            continue
        n = s["looks"][-1]
        b = None if c.b is None else c.b[:n]
        p[i, :, 0] = [float(x) for x in pvalues(c.a[:n], b, c.sesoi, c.paired, c.expect, c.alternative)]
        levels[i] = level_table(tuple(s["looks"]), n_max, m, alpha, spending, _two_sided(c))
    testable = np.array([[bool(state[c.name]["looks"]) and not state[c.name]["rejected"]] for c in claims])
    after = holm_look(p, levels, rejected, testable)[..., 0]
    share = alpha / max(1, m - int(after.sum()))
    decisions = []
    for i, c in enumerate(claims):
        s = state[c.name]
        s["rejected"] = [h for h, r in zip(HYPOTHESES, after[i]) if r]
        n, n_max = (s["looks"][-1] if s["looks"] else c.n), c.plan.n_max
        status = DECIDED if s["rejected"] else AT_CAP if n >= n_max else CONTINUE
        effect = float(np.mean(c.a[:n]) - (0.0 if c.b is None else np.mean(c.b[:n])))
        verdict = verdicts.verdict(c.expect, effect, "mean", 0.0 if after[i, 0] else 1.0, 0.0 if after[i, 1] else 1.0)
        needed = math.nan
        if status == AT_CAP:
            d = c.a[:n] - c.b[:n] if c.paired and c.b is not None else c.a[:n]
            sd = (float(np.std(d, ddof=1)) if c.paired or c.b is None
                  else math.sqrt((np.var(c.a[:n], ddof=1) + np.var(c.b[:n], ddof=1)) / 2))
            needed = stats.n_for_t(c.sesoi, sd, c.paired or c.b is None, share)
        j = max(1, m - int(after.sum())) - 1
        decisions.append(Decision(c.name, status, tuple(s["rejected"]), verdict, n, len(s["looks"]), share,
                                  (float(levels[i, 0, j]), float(levels[i, 1, j])), (float(p[i, 0, 0]), float(p[i, 1, 0])),
                                  runs_next=(min(c.plan.per_round, n_max - n) * c.plan.arms if status == CONTINUE else 0),
                                  runs_needed=needed))
    return decisions, state


def decide_study(families: dict[str, list[Claim]], state: dict | None = None, alpha: float = stats.ALPHA,
                 spending: str = "obf") -> tuple[dict[str, list[Decision]], dict]:
    """``decide_family`` on each family alone (one error rate per family; a family's decisions
    never read another family's runs). ``state``: one entry per family."""
    state = state or {}
    out, new = {}, {}
    for name, claims in families.items():
        out[name], new[name] = decide_family(claims, state.get(name), alpha, spending)
    return out, new


def simulate(claims: list[Claim], alpha: float = stats.ALPHA, spending: str = "obf") -> tuple[np.ndarray, np.ndarray]:
    """The whole procedure on R simulated copies of one family at once: each claim's ``a`` (and
    ``b``) is [R, n_max] in seed order; every round, each open claim is read at its next planned
    look (``Plan.schedule``), a claim past its last look at that look again, exactly as
    ``decide_family`` does round by round. Returns (rejected [C, 2, R], runs per arm used [C, R])."""
    reps = claims[0].a.shape[0]
    schedules = [c.plan.schedule() for c in claims]
    m = 2 * len(claims)
    p = np.ones((len(claims), 2, reps))
    rejected = np.zeros((len(claims), 2, reps), bool)
    used = np.zeros((len(claims), reps), int)
    for k in range(max(map(len, schedules))):
        levels = np.empty((len(claims), 2, m))
        for i, (c, looks) in enumerate(zip(claims, schedules)):
            look = min(k, len(looks) - 1)
            if k == look:
                live = ~rejected[i].any(axis=0)
                n = looks[k]
                b = None if c.b is None else c.b[live, :n]
                p[i][:, live] = pvalues(c.a[live, :n], b, c.sesoi, c.paired, c.expect, c.alternative)
                used[i, live] = n
            levels[i] = level_table(looks[:look + 1], c.plan.n_max, m, alpha, spending, _two_sided(c))
        rejected = holm_look(p, levels, rejected, ~rejected.any(axis=1))
    return rejected, used
