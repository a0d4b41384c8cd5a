"""The smallest Gaussian budget a scene needs: the search and its decisions (docs/studies.md,
"The smallest model").

The smallest model is the fewest Gaussians whose held-out quality is within the metric's SESOI
(``harness.spec.metrics.sesoi``: 0.2 dB of PSNR, docs/sesoi.md) of the best model trained for
the scene, with the interval over seeds showing it is settled. ``find(measure, ...)`` searches
for it; ``measure(budget)`` returns the per-seed values at a budget (``cli.budget`` trains
them as study runs; the tests pass curves). Every interval is the 90% Welch interval of a
difference of means, the interval of the two one-sided tests at α = 0.05 (TOST, Schuirmann
1987: ``statsmodels.stats.weightstats.ttost_ind`` rejects at ±SESOI exactly when it lies
inside), so its upper end is the one-sided 95% bound:

1. **Doubling**: from ``start`` the budget doubles until a doubling's gain is *settled small*:
   its interval lies inside ±SESOI (equivalence), or below zero (more Gaussians score settled
   worse). A gain whose interval is wide (it reaches ±SESOI) does not stop the search, whatever
   its mean: "the interval includes zero" is not "no gain".
2. **The best model**: the budget tried with the highest mean.
3. **Bisection**: the smallest doubling budget whose gap to the best (best − candidate) has its
   upper bound below the SESOI is sufficient; the budgets between it and the doubling budget
   below are bisected (to about an eighth of the budget), each judged by the same bound.
4. **At the cap**: when doubling reaches ``max_budget`` unsettled the search says so, with the
   runs per budget the last doubling's equivalence test would need for 80% power at the SD the
   runs show (``runs_needed``, statsmodels' t-test power) — or that it still gains the SESOI.

The values are those of the search's ``metric``: raw held-out PSNR (``psnr``) or the
colour-aligned one (``psnr_cc``), which leaves out the held-out camera's colour that no model
budget can learn (the registry's ``budget_metrics``: the held-out metrics in dB).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy import stats

from harness.spec.metrics import budget_metrics, phrase

ALPHA = 0.05  # each one-sided test; the two-sided interval is 1 − 2α = 90%
POWER = 0.8
N_MAX = 1000  # runs per budget beyond which "needed" is reported as more than this


@dataclass(frozen=True)
class Gain:
    """mean(high) − mean(low), with its 90% Welch interval (the TOST's)."""

    mean: float
    low: float
    high: float

    def equivalent(self, sesoi: float) -> bool:
        """The whole interval lies inside ±``sesoi`` (TOST rejects both one-sided nulls)."""
        return -sesoi < self.low and self.high < sesoi

    def settled_below(self, sesoi: float) -> bool:
        """The one-sided 95% upper bound lies below ``sesoi``."""
        return self.high < sesoi


def gain(low: np.ndarray, high: np.ndarray) -> Gain:
    """The difference from the runs ``low`` to the runs ``high`` (per-seed values), Welch."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    diff = float(high.mean() - low.mean())
    if len(low) < 2 or len(high) < 2:
        return Gain(diff, math.nan, math.nan)
    if np.ptp(low) == 0 and np.ptp(high) == 0:  # no spread: the difference is exact
        return Gain(diff, diff, diff)
    ci = stats.ttest_ind(high, low, equal_var=False).confidence_interval(1 - 2 * ALPHA)
    return Gain(diff, float(ci.low), float(ci.high))


def doubling_verdict(g: Gain, sesoi: float) -> str:
    """``equivalent`` (inside ±SESOI) or ``loses`` (settled below zero): doubling stops;
    ``gains`` (settled above zero) or ``unsettled``: it goes on."""
    if g.equivalent(sesoi):
        return "equivalent"
    if g.high < 0:
        return "loses"
    return "gains" if g.low > 0 else "unsettled"


def pooled_sd(*runs: np.ndarray) -> float:
    """The SD of the runs about their own budgets' means (ddof 1 per budget), pooled."""
    groups = [np.asarray(r, float) for r in runs if len(r) > 1]
    dof = sum(len(r) - 1 for r in groups)
    return math.sqrt(sum(((r - r.mean()) ** 2).sum() for r in groups) / dof) if dof else math.nan


def tost_power(sesoi: float, sd: float, n: int | np.ndarray, alpha: float = ALPHA) -> float | np.ndarray:
    """Power of the two one-sided tests at ±``sesoi`` with ``n`` runs per budget (a number or an
    array of them) when the true difference is 0: both one-sided t-tests must reject,
    1 − 2(1 − one-sided power) (statsmodels)."""
    from statsmodels.stats.power import TTestIndPower

    one = TTestIndPower().power(sesoi / sd, np.asarray(n, dtype=float), alpha, alternative="larger")
    return np.maximum(0.0, 2 * one - 1)


def runs_needed(sesoi: float, sd: float, alpha: float = ALPHA) -> float:
    """Runs per budget for 80% power of the doubling's equivalence test at SD ``sd``, if the
    doubling gains nothing: the smallest whole number (inf beyond ``N_MAX``, NaN without a spread)."""
    if not (sd > 0 and sesoi > 0):
        return math.nan
    n = np.arange(2, N_MAX + 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        power = np.nan_to_num(tost_power(sesoi, sd, n, alpha), nan=1.0)  # NaN far out in the tail, where it is 1
    enough = np.flatnonzero(power >= POWER)
    return float(n[enough[0]]) if len(enough) else math.inf


def midpoint(low: int, high: int, step: int = 100) -> int:
    """The budget halfway between ``low`` and ``high``, rounded to ``step`` Gaussians."""
    return int(round((low + high) / 2 / step) * step)


METRICS = {m: phrase(m) for m in budget_metrics()}  # what a search may judge: name -> how prose names it


@dataclass
class BudgetSearch:
    """What the search tried and found."""

    scene: str
    sesoi: float  # dB: within this of the best is "as good"
    metric: str = "psnr"  # what the search judges: psnr or psnr_cc (METRICS)
    scores: dict[int, list[float]] = field(default_factory=dict)  # budget -> per-seed value of ``metric``
    seconds: dict[int, list[float]] = field(default_factory=dict)  # budget -> per-seed train seconds
    faded: dict[int, list[float]] = field(default_factory=dict)  # budget -> per-seed Gaussians drawn nowhere
    alive: dict[int, list[float]] = field(default_factory=dict)  # budget -> per-seed n_gaussians − n_faded
    model_bytes: dict[int, list[float]] = field(default_factory=dict)  # budget -> per-seed bytes of the model
    trainers: set[str] = field(default_factory=set)  # trainer fingerprints of the runs read
    steps: list[str] = field(default_factory=list)  # one line per decision
    chosen: int | None = None
    saturated: bool = False  # True: a doubling's gain was settled small (equivalent, or a settled loss)
    runs_needed: float = math.nan  # unsaturated at the cap: runs per budget the last doubling's TOST needs
    still_gains: bool = False  # unsaturated at the cap and the last doubling's gain settled above zero
    control: list[float] = field(default_factory=list)  # a known-size scene: the runs started from the truth

    @property
    def best(self) -> int:
        """The budget tried with the highest mean (the best model trained for the scene)."""
        return max(self.scores, key=lambda b: (float(np.mean(self.scores[b])), -b))

    def gap(self, budget: int | None = None) -> Gain:
        """best − ``budget`` (default: the chosen one), with its interval."""
        return gain(np.array(self.scores[self.chosen if budget is None else budget]), np.array(self.scores[self.best]))

    def sufficient(self, budget: int) -> bool:
        """The best itself, or settled within the SESOI of it (upper bound of best − budget)."""
        return budget == self.best or self.gap(budget).settled_below(self.sesoi)

    @property
    def settled(self) -> bool:
        """The answer is settled: doubling saturated and the chosen budget's gap is bounded."""
        return self.saturated and self.chosen is not None and self.sufficient(self.chosen)

    def seconds_saved(self) -> float:
        return float(np.mean(self.seconds[self.best]) - np.mean(self.seconds[self.chosen]))


Measure = Callable[[int], np.ndarray]  # budget -> per-seed values of the metric (trains what it lacks)


def find(found: BudgetSearch, measure: Measure, start: int, max_budget: int) -> BudgetSearch:
    """Doubling, then bisection (module docstring); ``found`` collects the decisions and is
    returned with ``chosen`` set. ``measure`` fills ``found.scores`` (and whatever else it reads)."""
    sesoi = found.sesoi
    doubled = [start]
    measure(start)
    while True:
        low, high = doubled[-1], doubled[-1] * 2
        if high > max_budget:
            if len(doubled) < 2:
                found.steps.append(f"{high} would exceed --max {max_budget}: nothing to compare {low} with")
            else:
                _at_cap(found, doubled[-2], low, max_budget)
            found.chosen, found.saturated = found.best, False
            return found
        g = gain(measure(low), measure(high))
        verdict = doubling_verdict(g, sesoi)
        doubled.append(high)
        found.steps.append(f"{low} -> {high}: {g.mean:+.3f} dB [{g.low:+.3f}, {g.high:+.3f}]: {verdict}")
        if verdict in ("equivalent", "loses"):
            break
    found.saturated = True
    sufficient = [b for b in doubled if found.sufficient(b)]
    hi = sufficient[0]
    below = [b for b in doubled if b < hi]
    lo = below[-1] if below else None
    while lo is not None and hi - lo > max(hi // 8, 100):  # bisect: about an eighth of the budget
        mid = midpoint(lo, hi)
        if mid in (lo, hi):
            break
        measure(mid)
        ok = found.sufficient(mid)
        g = found.gap(mid)
        found.steps.append(f"{mid}: {g.mean:+.3f} dB [{g.low:+.3f}, {g.high:+.3f}] below the best ({found.best})"
                           f" -> {'sufficient' if ok else 'not settled within the SESOI'}")
        lo, hi = (lo, mid) if ok else (mid, hi)
    found.chosen = hi
    return found


def _at_cap(found: BudgetSearch, low: int, high: int, max_budget: int) -> None:
    """The last doubling (``low`` -> ``high``) is unsettled at the cap: say what would settle it."""
    g = gain(found.scores[low], found.scores[high])
    found.still_gains = g.low > found.sesoi
    found.runs_needed = runs_needed(found.sesoi, pooled_sd(found.scores[low], found.scores[high]))
    need = (f"{found.runs_needed:.0f} runs per budget" if math.isfinite(found.runs_needed) else
            f"more than {N_MAX} runs per budget" if found.runs_needed == math.inf else "runs with a spread")
    found.steps.append(f"{high * 2} would exceed --max {max_budget}: not settled at {high}; "
                       + ("the last doubling still gains more than the SESOI (raise --max)" if found.still_gains else
                          f"settling the last doubling's equivalence (80% power at its SD) needs {need}"))
