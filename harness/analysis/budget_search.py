"""The smallest Gaussian budget a scene needs: the decisions of the budget search.

``cli.budget`` doubles the budget until doubling gains less than ``threshold`` dB, then
bisects between the last insufficient and the first sufficient budget. The decisions are
pure functions of the runs' PSNRs per budget:

- ``gain(low, high)``: mean PSNR(high) − mean PSNR(low) with its 95% Welch interval;
- ``sufficient(candidate, best, threshold)``: the candidate is within ``threshold`` dB of the
  best budget tried (point estimate; the interval says whether that is settled).

The PSNR is the search's ``metric``: raw held-out PSNR (``psnr``) or the colour-aligned one
(``psnr_cc``), which leaves out the held-out camera's colour that no model budget can learn
(the registry's ``budget_metrics``: the held-out metrics in dB).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from harness.spec.metrics import budget_metrics, phrase


@dataclass(frozen=True)
class Gain:
    """mean(high) − mean(low) in dB, with its 95% Welch interval."""

    mean: float
    low: float
    high: float

    def settled_below(self, threshold: float) -> bool:
        """The whole interval lies below ``threshold``."""
        return self.high < threshold


def gain(low: np.ndarray, high: np.ndarray) -> Gain:
    """PSNR gain from the runs at one budget (``low``) to those at a larger one (``high``)."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    diff = float(high.mean() - low.mean())
    if len(low) < 2 or len(high) < 2:
        return Gain(diff, math.nan, math.nan)
    ci = stats.ttest_ind(high, low, equal_var=False).confidence_interval(0.95)
    return Gain(diff, float(ci.low), float(ci.high))


def sufficient(candidate: np.ndarray, best: np.ndarray, threshold: float) -> bool:
    """Whether the candidate budget's mean PSNR is within ``threshold`` dB of the best's."""
    return float(np.mean(best) - np.mean(candidate)) < threshold


def midpoint(low: int, high: int, step: int = 100) -> int:
    """The budget halfway between ``low`` and ``high``, rounded to ``step`` Gaussians."""
    return int(round((low + high) / 2 / step) * step)


METRICS = {m: phrase(m) for m in budget_metrics()}  # what a search may judge: name -> how prose names it


@dataclass
class BudgetSearch:
    """What the search tried and found."""

    scene: str
    threshold: float
    metric: str = "psnr"  # what the search judges: psnr or psnr_cc (METRICS)
    scores: dict[int, list[float]] = field(default_factory=dict)  # budget -> per-seed value of ``metric``
    seconds: dict[int, list[float]] = field(default_factory=dict)  # budget -> per-seed train seconds
    faded: dict[int, list[float]] = field(default_factory=dict)  # budget -> per-seed Gaussians drawn nowhere
    trainers: set[str] = field(default_factory=set)  # trainer fingerprints of the runs read
    steps: list[str] = field(default_factory=list)  # one line per decision
    chosen: int | None = None
    saturated: bool = False  # False: doubling still gained at the largest budget allowed

    @property
    def best(self) -> int:
        return max(self.scores)

    def gap(self) -> Gain:
        """The chosen budget's PSNR deficit to the largest budget tried."""
        return gain(np.array(self.scores[self.chosen]), np.array(self.scores[self.best]))

    def seconds_saved(self) -> float:
        return float(np.mean(self.seconds[self.best]) - np.mean(self.seconds[self.chosen]))
