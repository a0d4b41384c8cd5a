"""The forest plot of ``reports/index.md``: every counted claim at a glance.

One row per counted hypothesis: our effect with the interval its verdict used — the
Holm-adjusted one (``verdicts.adjusted_level``: at the confidence of the Holm step that decided
the row, so it excludes 0, or lies inside ±SESOI for an equivalence, exactly when the test
rejects; ``disagreements`` lists any row whose interval is not its test's dual and says
otherwise) — in units of the claim's smallest effect of interest (SD ratios on a log scale:
log(ratio) / log(SESOI)), so ±1 is the band of effects too small to matter (shaded), signed
so that the direction the claim expects points right (a "lower" claim's effect is mirrored);
the paper's own effect per dataset as a hollow diamond, signed alike; colour by verdict; ⚑ on
a claim registered after its runs. ``forest_plot`` returns what it drew (``Forest.drawn``). Existential claims and descriptions have no effect
of this kind and are left out (their row in the table says so), as are rows that were not tested.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from harness.analysis import verdicts as V  # noqa: E402
from harness.report.plots import save_figure  # noqa: E402

COLOURS = {V.REPRODUCED: "#2a9d4a", V.CONTRADICTED: "#c0392b", V.EQUIVALENT: "#2c6fbb", V.INCONCLUSIVE: "#8c8c8c"}


def expected_sign(row: pd.Series) -> float:
    """+1 when the claim expects a higher (or not lower, or equal) value, −1 when lower."""
    return -1.0 if row.expect in ("lower", "not_higher") else 1.0


def paper_points(row: pd.Series) -> list[tuple[str, float]]:
    """The paper's effects of ``row`` per dataset, in SESOI units (signed as ``expected_sign``)."""
    out = []
    for item in str(row.paper_effects or "").split(";"):
        if "=" not in item:
            continue
        name, value = item.rsplit("=", 1)
        v = float(value)
        if row.test == "variance":
            out.append((name, expected_sign(row) * math.log(v) / math.log(row.sesoi) if v > 0 else math.nan))
        else:
            out.append((name, expected_sign(row) * v / row.sesoi))
    return out


def adjusted(row: pd.Series) -> tuple[float, float, float]:
    """(effect, low, high) in SESOI units, signed so that the claimed direction is positive, with
    the interval the verdict used (``ci_adj_*``; a frame from before those columns: the 95% CI)."""
    low, high = row.get("ci_adj_low", math.nan), row.get("ci_adj_high", math.nan)
    if not (isinstance(low, float) and np.isfinite(low) and np.isfinite(high)):
        low, high = row.ci_low, row.ci_high
    scaled = row.copy()
    scaled["ci_low"], scaled["ci_high"] = low, high
    effect, lo, hi = (expected_sign(row) * v for v in V.in_sesoi_units(scaled))
    return effect, min(lo, hi), max(lo, hi)


def drawn_rows(frame: pd.DataFrame) -> pd.DataFrame:
    """The rows the plot draws: counted rows with a verdict on an effect that has a SESOI band
    (existential claims and descriptions have none; untested rows nothing to draw)."""
    return frame[frame.verdict.isin(list(COLOURS)) & ~frame.test.isin(["decoupled", "dissociated", "spread"])
                 ].reset_index(drop=True)


def disagreements(frame: pd.DataFrame) -> list[str]:
    """Rows whose drawn interval says otherwise than their verdict: one decided by a difference
    (or minimal-effect) test whose interval excludes 0 (lies outside ±SESOI) exactly when it
    rejects, one decided by equivalence whose interval lies inside ±SESOI exactly when it
    rejects. An interval dual to its test (every t-based one) never disagrees; a bootstrap
    interval of an SD ratio beside a Pitman–Morgan or Brown–Forsythe test, or the weakest
    contrast's beside a test of all of them, can."""
    out = []
    for _, r in drawn_rows(frame).iterrows():
        _, lo, hi = adjusted(r)
        inside = -1 <= lo and hi <= 1  # what TOST rejects
        # what the difference test rejects; a "≈" claim's p is the minimal-effect test's: outside ±SESOI
        away = (lo > 1 or hi < -1) if r.expect == "equivalent" else (lo > 0 or hi < 0)
        if V.by_equivalence(r):
            agrees = inside
        elif r.verdict == V.INCONCLUSIVE:
            agrees = not inside and not away
        else:
            agrees = away
        if not agrees:
            out.append(f"{r.study}.{r.id}" if "study" in r else str(r.id))
    return out


@dataclass(frozen=True)
class Forest:
    """The figure and, per drawn row, what was drawn: ``study``, ``id``, ``effect``, ``low``,
    ``high`` (SESOI units, the claimed direction positive) and ``level`` (its confidence)."""

    path: Path
    drawn: pd.DataFrame


def forest_plot(frame: pd.DataFrame, path: Path, title: str = "Every counted claim against its smallest effect of interest"
                ) -> Forest | None:
    """Draw ``frame`` (``verdicts.decide`` output with a ``study`` column); None when nothing to draw."""
    rows = drawn_rows(frame)
    if rows.empty:
        return None
    height = 0.42 * len(rows) + 1.6
    fig, ax = plt.subplots(figsize=(9.0, height))
    ax.axvspan(-1, 1, color="#e8e8e8", zorder=0, label="within ±SESOI")
    ax.axvline(0, color="black", lw=0.8)
    labels, drawn = [], []
    for y, (_, r) in enumerate(rows.iterrows()):
        effect, lo, hi = adjusted(r)
        colour = COLOURS[r.verdict]
        ax.plot([lo, hi], [y, y], color=colour, lw=2.2, zorder=2)
        ax.plot([effect], [y], "o", color=colour, ms=6, zorder=3)
        for _, p in paper_points(r):
            ax.plot([p], [y], "D", mfc="none", mec="black", ms=6, zorder=4)
        mark = " ⚑" if r.get("registered_before_runs", "") == "no" else ""
        labels.append(f"{r.study}: {r.id}  [{r.group}]{mark}")
        drawn.append({"study": r.study, "id": r.id, "effect": effect, "low": lo, "high": hi,
                      "level": r.get("ci_adj_level", math.nan)})
    ax.set_xscale("symlog", linthresh=3, linscale=1.5)  # ±3 SESOI linear; a 40-SESOI effect does not squash the rest
    ax.set_yticks(range(len(rows)), labels, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("effect / smallest effect of interest (symlog), the claimed direction to the right;\n"
                  "SD ratios: log ratio / log SESOI; each row's Holm-adjusted interval (the one its verdict used)")
    handles = [plt.Line2D([], [], color=c, marker="o", lw=2, label=v) for v, c in COLOURS.items()]
    handles += [plt.Line2D([], [], color="black", marker="D", mfc="none", lw=0, label="paper's effect (per dataset)")]
    ax.legend(handles=handles, fontsize=7, loc="lower right", framealpha=0.9)
    ax.set_title(title, fontsize=10)
    ax.grid(axis="x", alpha=0.3)
    return Forest(save_figure(fig, path), pd.DataFrame(drawn))
