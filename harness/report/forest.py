"""The forest plot that opens ``reports/index.md``: every claim at a glance.

One row per counted hypothesis: our effect with its 95% CI in units of the claim's smallest
effect of interest (SD ratios on a log scale: log(ratio) / log(SESOI)), so ±1 is the band of
effects too small to matter (shaded), signed so that the direction the claim expects points
right (a "lower" claim's effect is mirrored); the paper's own effect per dataset as a hollow
diamond, signed alike; colour by verdict. Existential claims and descriptions have no effect
of this kind and are left out (their row in the table says so), as are rows that were not tested.
"""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
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


def forest_plot(frame: pd.DataFrame, path: Path, title: str = "Every counted claim against its smallest effect of interest"
                ) -> Path | None:
    """Draw ``frame`` (``verdicts.decide`` output with a ``study`` column); None when nothing to draw."""
    rows = frame[frame.verdict.isin(list(COLOURS)) & ~frame.test.isin(["decoupled", "dissociated", "spread"])
                 ].reset_index(drop=True)
    if rows.empty:
        return None
    height = 0.42 * len(rows) + 1.6
    fig, ax = plt.subplots(figsize=(9.0, height))
    ax.axvspan(-1, 1, color="#e8e8e8", zorder=0, label="within ±SESOI")
    ax.axvline(0, color="black", lw=0.8)
    labels = []
    for y, (_, r) in enumerate(rows.iterrows()):
        effect, lo, hi = (expected_sign(r) * v for v in V.in_sesoi_units(r))
        lo, hi = min(lo, hi), max(lo, hi)
        colour = COLOURS[r.verdict]
        ax.plot([lo, hi], [y, y], color=colour, lw=2.2, zorder=2)
        ax.plot([effect], [y], "o", color=colour, ms=6, zorder=3)
        for _, p in paper_points(r):
            ax.plot([p], [y], "D", mfc="none", mec="black", ms=6, zorder=4)
        labels.append(f"{r.study}: {r.id}  [{r.group}]")
    ax.set_xscale("symlog", linthresh=3, linscale=1.5)  # ±3 SESOI linear; a 40-SESOI effect does not squash the rest
    ax.set_yticks(range(len(rows)), labels, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("effect / smallest effect of interest (symlog), the claimed direction to the right;\n"
                  "SD ratios: log ratio / log SESOI; 95% CI")
    handles = [plt.Line2D([], [], color=c, marker="o", lw=2, label=v) for v, c in COLOURS.items()]
    handles += [plt.Line2D([], [], color="black", marker="D", mfc="none", lw=0, label="paper's effect (per dataset)")]
    ax.legend(handles=handles, fontsize=7, loc="lower right", framealpha=0.9)
    ax.set_title(title, fontsize=10)
    ax.grid(axis="x", alpha=0.3)
    return save_figure(fig, path)
