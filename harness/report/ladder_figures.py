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
    COLLAPSE_DB,
    COLLAPSE_RULE,
    COLLAPSED,
    COMPONENT,
    METHOD,
    METRIC,
    Ladder,
    classify_all,
    first_breaks,
    ladder_table,
    ladders_of,
)
from harness.report.plots import save_figure  # noqa: E402
from harness.spec.study_schema import StudyScene  # noqa: E402

LOG_X_LADDERS = ("lr_scale",)  # ladders whose rungs are multiplicative: plotted on a log axis


# --- Markdown ------------------------------------------------------------------------


def _num(x: float) -> str:
    return "—" if math.isnan(x) else f"{x:.2f}"


def cell_text(r: pd.Series) -> str:
    """``30.12 ± 0.20 (fail 1/2: 0/1/0)``: finished runs' PSNR, failed of attempted:
    crashed/diverged/collapsed."""
    fails = r.n_crashed + r.n_diverged + r.n_collapsed
    return (f"{_num(r.psnr_mean)} ± {_num(r.psnr_std)} (fail {fails}/{r.n_attempted}:"
            f" {r.n_crashed}/{r.n_diverged}/{r.n_collapsed})")


def ladder_markdown(table: pd.DataFrame, breaks: pd.DataFrame, ladder: str) -> list[str]:
    """One ladder's table (rows: rungs; columns: methods) and its first-break line."""
    sub = table[(table.ladder == ladder) & (table.role == METHOD)]
    methods = list(dict.fromkeys(sub.variant))
    lines = [f"### Ladder `{ladder}`", "", f"| {ladder} | cell | " + " | ".join(methods) + " |",
             "|---:|---|" + "---|" * len(methods)]
    for step, rung in sub.groupby("step", sort=True):
        cells = rung.set_index("variant")
        first = rung.iloc[0]
        tag = " (base)" if step == 0 else ""
        lines.append(f"| {first.rung:g}{tag} | {first.scene_label} | "
                     + " | ".join(cell_text(cells.loc[v]) if v in cells.index else "not run" for v in methods)
                     + " |")
    b = breaks[(breaks.ladder == ladder) & (breaks.role == METHOD)]
    lines += ["", "First rung with a failure: " + "; ".join(f"`{r.variant}` {r.text}" for r in b.itertuples())
              + ".", ""]
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
        lines += [f"#### Variants on {sub.scene_label.iloc[0]}", "",
                  "| variant | role | finished PSNR (mean ± std) | ok / attempted | crashed | diverged | collapsed |",
                  "|---|---|---|---:|---:|---:|---:|"]
        for r in sub.itertuples():
            no_ref = math.isnan(r.reference_psnr) and r.step > 0
            unjudged |= no_ref
            collapsed = "—" if no_ref else str(r.n_collapsed)
            lines.append(f"| `{r.variant}` | {r.role} | {_num(r.psnr_mean)} ± {_num(r.psnr_std)} |"
                         f" {r.n_ok} / {r.n_attempted} | {r.n_crashed} | {r.n_diverged} | {collapsed} |")
        lines.append("")
    if unjudged:
        lines += ["Collapsed \"—\": the variant has no finished base-cell runs, and extends no variant that has, to judge a collapse against.", ""]
    return (["### Component variants per cell", "", *lines] if lines else [])


def ladders_markdown(table: pd.DataFrame, breaks: pd.DataFrame, figure: str = "") -> str:
    """The report's section: the rule, a table and a first-break line per ladder, the
    component variants per cell and (when given) the figure."""
    lines = ["Each ladder starts at its base cell and makes one condition harder, rung by rung; rows are"
             " in that order. " + COLLAPSE_RULE + " Interrupted, running and missing runs are not attempted."
             " Each cell: mean ± std PSNR of the finished runs (collapsed ones included), then"
             " \"fail k/n: c/d/x\": k of n attempted runs failed, c crashed, d diverged, x collapsed.", ""]
    if table.empty:
        return "\n".join(lines + ["No runs on any ladder."])
    for lad in dict.fromkeys(table.ladder):
        lines += ladder_markdown(table, breaks, lad)
    lines += components_markdown(table)
    if figure:
        lines += [f"![PSNR and failure rate along each ladder]({figure})", ""]
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


def _breakdown(crashed: int, diverged: int, collapsed: int) -> str:
    """``1 crash + 1 div``: the nonzero failure counts of one rung."""
    parts = [(crashed, "crash"), (diverged, "div"), (collapsed, "coll")]
    return " + ".join(f"{n} {word}" for n, word in parts if n)


def ladder_plot(table: pd.DataFrame, runs: pd.DataFrame, scenes: Sequence[StudyScene],
                title: str, path: Path) -> Path:
    """One column per ladder: mean ± std PSNR (collapsed runs as hollow triangles) on top,
    failure rate with crashed/diverged/collapsed counts below; one line per method."""
    lads = ladders_of(scenes)
    fig, axes = plt.subplots(2, len(lads), figsize=(min(4.2, 15.0 / len(lads)) * len(lads), 7.0), squeeze=False,
                             sharey="row",
                             constrained_layout=True)
    methods = list(dict.fromkeys(table.loc[table.role == METHOD, "variant"]))
    for col, lad in enumerate(lads):
        top, bottom = axes[0][col], axes[1][col]
        for k, v in enumerate(methods):
            sub = table[(table.ladder == lad.name) & (table.variant == v) & (table.role == METHOD)]
            style = {"color": f"C{k}", "marker": "osD^"[k % 4]}
            top.errorbar(sub.rung, sub.psnr_mean, yerr=sub.psnr_std.fillna(0), capsize=3, label=v, **style)
            bad = runs[(runs.ladder == lad.name) & (runs.variant == v) & (runs.outcome == COLLAPSED)]
            top.scatter(bad.rung, bad[METRIC], marker="v", s=60, facecolors="none", edgecolors=f"C{k}",
                        label=f"{v}: collapsed run" if len(bad) else None, zorder=4)
            bottom.plot(sub.rung, 100 * sub.failure_rate, **style, label=v)
            for r in sub[sub.failure_rate > 0].itertuples():
                bottom.annotate(_breakdown(r.n_crashed, r.n_diverged, r.n_collapsed), (r.rung, 100 * r.failure_rate),
                                textcoords="offset points", xytext=(4, 4 + 9 * k), fontsize=7, color=f"C{k}")
        for ax in (top, bottom):
            _axis(ax, lad)
        top.set_title(f"ladder {lad.name} (base: {lad.base.scene.title})")
        bottom.set_xlabel(f"{lad.name} (harder →)")
        bottom.set_ylim(-5, 110)
    axes[0][0].set_ylabel("PSNR (dB), finished runs: mean ± std")
    axes[1][0].set_ylabel("failed runs (% of attempted)")
    if axes[0][0].get_legend_handles_labels()[0]:  # a ladder with no finished cell has nothing to label
        axes[0][0].legend(fontsize=7, loc="best")
    fig.suptitle(f"{title}\nfailed runs: crash(ed), div(erged), coll(apsed) = finished"
                 f" > {COLLAPSE_DB:g} dB below the method's base-cell mean")
    return save_figure(fig, path)


def write(df: pd.DataFrame, scenes: Sequence[StudyScene], out: Path, title: str) -> str:
    """``ladders.csv`` and ``ladders.png`` under ``out``; returns the Markdown section."""
    table = ladder_table(df, scenes)
    table.to_csv(out / "ladders.csv", index=False)
    if table.empty:
        return ladders_markdown(table, pd.DataFrame())
    ladder_plot(table, classify_all(df, scenes), scenes, title, out / "ladders.png")
    return ladders_markdown(table, first_breaks(table), "ladders.png")
