"""The stability ladders in a report: Markdown section, ``ladders.png`` and ``ladders.csv``.

The numbers come from ``analysis.ladder_breaks`` (``ladder_table``, ``first_breaks``,
``classify_all``); ``write`` makes every file ``study report`` shows for them.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from harness.analysis.ladder_breaks import (  # noqa: E402
    BREAKS,
    COMPONENT,
    FAILURE_RULE,
    KIND_NAMES,
    KINDS,
    METHOD,
    QUALITY,
    Ladder,
    changing_rungs,
    first_breaks,
    ladder_table,
    ladders_of,
)
from harness.report.plots import MAX_WIDTH_IN, save_figure  # noqa: E402
from harness.spec.study_schema import StudyScene  # noqa: E402

LOG_X_LADDERS = ("lr_scale", "stride", "init_points")  # multiplicative rungs: plotted on a log axis


# --- Markdown ------------------------------------------------------------------------


def _num(x: float) -> str:
    return "—" if math.isnan(x) else f"{x:.2f}"


def rate_text(k: int, n: int, low: float, high: float) -> str:
    """``1/3 (1–91 %)``: k of n attempted with the exact 95 % interval of the rate (``≤ 71 %`` for
    none, ``≥ 29 %`` for all)."""
    if not n:
        return "—"
    if k == 0:
        return f"0/{n} (≤ {100 * high:.0f} %)"
    if k == n:
        return f"{k}/{n} (≥ {100 * low:.0f} %)"
    return f"{k}/{n} ({100 * low:.0f}–{100 * high:.0f} %)"


HEADER = ("| runs | colour-aligned PSNR | raw PSNR | " + " | ".join(KIND_NAMES[k] for k in KINDS)
          + " | vs base (95 % CI) |")


def loss_text(r: pd.Series) -> str:
    """``−1.50 [−2.10, −0.90] settled``: the cell's colour-aligned PSNR minus the base cell's."""
    d = r.get("loss_diff", math.nan)
    if d is None or math.isnan(d):
        return "—"
    lo, hi = r.get("loss_diff_low", math.nan), r.get("loss_diff_high", math.nan)
    text = f"{d:+.2f}" + ("" if math.isnan(lo) else f" [{lo:+.2f}, {hi:+.2f}]")
    return text + (" **loss**" if r.get("loss_settled", 0.0) == 1.0 else "")


def row_cells(r: pd.Series) -> str:
    """The columns of ``HEADER`` for one (rung, variant) row."""
    kinds = " | ".join(rate_text(int(r[f"n_{k}"]), int(r.n_attempted), r[f"rate_{k}_low"], r[f"rate_{k}_high"])
                       for k in KINDS)
    return (f"| {r.n_attempted} | {_num(r.psnr_cc_mean)} ± {_num(r.psnr_cc_std)} |"
            f" {_num(r.psnr_mean)} ± {_num(r.psnr_std)} | {kinds} | {loss_text(r)} |")


def ladder_markdown(table: pd.DataFrame, breaks: pd.DataFrame, ladder: str) -> list[str]:
    """One ladder's table (a row per rung and method) and its first-break lines."""
    sub = table[(table.ladder == ladder) & (table.role == METHOD)]
    lines = [f"### Ladder `{ladder}`", "", f"| {ladder} | cell | method " + HEADER,
             "|---:|---|---|---:|---:|---:|" + "---:|" * (len(KINDS) + 1)]
    for r in sub.sort_values("step", kind="stable").itertuples():
        tag = " (base)" if r.step == 0 else ""
        lines.append(f"| {r.rung:g}{tag} | {r.scene_label} | `{r.variant}` " + row_cells(pd.Series(r._asdict())))
    b = breaks[(breaks.ladder == ladder) & (breaks.role == METHOD)]
    lines += ["", "First rung that breaks a method (a crash, a divergence or a colour collapse): "
              + "; ".join(f"`{r.variant}` {r.text}" for r in b.itertuples()) + ".",
              "First rung with a settled quality loss (**loss**): "
              + "; ".join(f"`{r.variant}` {r.loss_text}" for r in b.itertuples()) + ".", ""]
    return lines


def components_markdown(table: pd.DataFrame) -> list[str]:
    """Per cell that runs component variants: every variant's PSNR and failure counts there."""
    cells = table.drop_duplicates(["scene", "variant"])  # a base cell appears once per ladder
    lines: list[str] = []
    unjudged = False
    for scene, sub in cells.groupby("scene", sort=False):
        if not (sub.role == COMPONENT).any():
            continue
        sub = sub.sort_values("role", key=lambda s: s != METHOD, kind="stable")
        lines += [f"#### Variants on {sub.scene_label.iloc[0]}", "", "| variant | role " + HEADER,
                  "|---|---|---:|---:|---:|" + "---:|" * (len(KINDS) + 1)]
        for r in sub.itertuples():
            unjudged |= math.isnan(r.reference_psnr) and r.step > 0
            lines.append(f"| `{r.variant}` | {r.role} " + row_cells(pd.Series(r._asdict())))
        lines.append("")
    if unjudged:
        lines += ["A variant with no finished base-cell runs, which extends no variant that has, is not judged"
                  " for quality loss (its count is 0 by default).", ""]
    return (["### Component variants per cell", "", *lines] if lines else [])


def seeds_markdown(table: pd.DataFrame) -> list[str]:
    """Where the failure rates change along a ladder, and how many runs each of those cells has."""
    change = changing_rungs(table)
    if change.empty:
        return ["No method's rate of any failure kind changes along a ladder.", ""]
    cells = change.drop_duplicates(["scene", "variant"])
    few = cells[cells.n_attempted < 5]
    text = ", ".join(f"{r.scene}/`{r.variant}` ({r.n_attempted})" for r in cells.itertuples())
    lines = [f"Cells where a method's failure rate changes from one rung to the next (attempted runs): {text}."]
    lines.append("Each has at least 5 runs." if few.empty else
                 f"{len(few)} of them {'has' if len(few) == 1 else 'have'} fewer than 5 runs: read their rates with"
                 " the interval.")
    return lines + [""]


def ladders_markdown(table: pd.DataFrame, breaks: pd.DataFrame, figure: str = "") -> str:
    """The report's section: the rule, a table and first-break lines per ladder, the component
    variants per cell, where the rates change and (when given) the figure."""
    lines = ["Each ladder starts at its base cell and makes one condition harder, rung by rung; rows are"
             " in that order. " + FAILURE_RULE + " Interrupted, running and missing runs are not attempted."
             " PSNR columns: mean ± std of the finished runs; \"vs base\": the rung's mean colour-aligned PSNR"
             " minus the base cell's, with its Welch interval, **loss** where the loss is settled.", ""]
    if table.empty:
        return "\n".join(lines + ["No runs on any ladder."])
    for lad in dict.fromkeys(table.ladder):
        lines += ladder_markdown(table, breaks, lad)
    lines += components_markdown(table)
    lines += seeds_markdown(table)
    if figure:
        lines += [f"![Colour-aligned PSNR and failure rates along each ladder]({figure})", ""]
    return "\n".join(lines).rstrip() + "\n"


# --- plot ----------------------------------------------------------------------------


def _axis(ax: plt.Axes, ladder: Ladder) -> None:
    """Rung values in ladder order: log scale where multiplicative, reversed when descending."""
    values = [r.value for r in ladder.rungs]
    if ladder.name in LOG_X_LADDERS and min(values) > 0:
        ax.set_xscale("log")
    ax.set_xticks(values, [f"{v:g}" for v in values])
    ax.minorticks_off()
    if ladder.descending:
        ax.invert_xaxis()
    ax.grid(alpha=0.3)


def ladder_plot(table: pd.DataFrame, scenes: Sequence[StudyScene], title: str, path: Path) -> Path:
    """One column per ladder, one line per method: colour-aligned PSNR (mean ± std, raw PSNR
    dashed) on top; below, the rate of breaking runs (crash, divergence or colour collapse) and
    the quality-loss rate dotted (their intervals are in the tables)."""
    lads = ladders_of(scenes)
    width = min(4.2, MAX_WIDTH_IN / len(lads)) * len(lads)
    fig, axes = plt.subplots(2, len(lads), figsize=(width, 7.0), squeeze=False, sharey="row",
                             constrained_layout=True)
    methods = list(dict.fromkeys(table.loc[table.role == METHOD, "variant"]))
    for col, lad in enumerate(lads):
        top, bottom = axes[0][col], axes[1][col]
        for k, v in enumerate(methods):
            sub = table[(table.ladder == lad.name) & (table.variant == v) & (table.role == METHOD)]
            style = {"color": f"C{k}", "marker": "osD^"[k % 4]}
            top.errorbar(sub.rung, sub.psnr_cc_mean, yerr=sub.psnr_cc_std.fillna(0), capsize=3,
                         label=f"{v}: colour-aligned", **style)
            top.plot(sub.rung, sub.psnr_mean, ls="--", alpha=0.6, label=f"{v}: raw", **style)
            # the first method hollow and larger, so a point two methods share shows both
            rates = {"ms": 9 - 3 * min(k, 1), "mfc": "none" if k == 0 else f"C{k}"}
            bottom.plot(sub.rung, 100 * sub.break_rate, label=f"{v}: breaks", **style, **rates)
            bottom.plot(sub.rung, 100 * sub[f"rate_{QUALITY}"], ls=":", label=f"{v}: quality loss", **style, **rates)
        for ax in (top, bottom):
            _axis(ax, lad)
        top.set_title(f"{lad.name}\n(base: {lad.base.scene.title})", fontsize=9)
        bottom.set_xlabel(f"{lad.name} (harder →)")
        bottom.set_ylim(-5, 105)
    axes[0][0].set_ylabel("PSNR (dB), finished runs")
    axes[1][0].set_ylabel("runs (% of attempted)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    h2, l2 = axes[1][0].get_legend_handles_labels()
    if handles or h2:
        fig.legend(handles + h2, labels + l2, fontsize=7, loc="outside lower center", ncols=4)
    fig.suptitle(f"{title}\nbreaks: {', '.join(KIND_NAMES[k] for k in BREAKS)}; quality loss dotted"
                 " (rates with their 95 % intervals: the tables)")
    return save_figure(fig, path)


def write(df: pd.DataFrame, scenes: Sequence[StudyScene], out: Path, title: str, baseline: str = "baseline") -> str:
    """``ladders.csv`` and ``ladders.png`` under ``out``; returns the Markdown section.
    ``baseline``: the variant whose held-out colour gap is each cell's reference."""
    table = ladder_table(df, scenes, baseline)
    table.to_csv(out / "ladders.csv", index=False)
    if table.empty:
        return ladders_markdown(table, pd.DataFrame())
    ladder_plot(table, scenes, title, out / "ladders.png")
    return ladders_markdown(table, first_breaks(table), "ladders.png")
