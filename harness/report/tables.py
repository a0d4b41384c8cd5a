"""Markdown and LaTeX tables in the paper's layout, built from ``aggregate.summarize``.

A ``Table`` is rows x columns of ``Cell`` (mean, std, note, rank); ``rank`` 1 marks the
best and 2 the second-best value of a column (bold / underline), taking the metric's
direction into account. Three layouts (``studies.LAYOUTS``):

- ``variants_x_scenes``: one table per metric, variants as rows, scenes + Average as columns;
- ``metrics_x_scenes``: metrics as rows (the baseline variant), no ranking (conventions);
- ``variants_x_metrics``: variants as rows, metrics as columns (scene average).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from harness.analysis.aggregate import AVERAGE
from harness.spec import metrics
from harness.spec.metrics import lower_is_better


def decimals(metric: str) -> int:
    """Decimals a table prints for ``metric`` (the metric registry)."""
    return metrics.decimals(metric)


def pretty(metric: str) -> str:
    """Label and direction arrow of ``metric`` (the metric registry)."""
    return metrics.title(metric)


@dataclass
class Cell:
    mean: float = math.nan
    std: float = math.nan
    digits: int = 2
    note: str = ""  # e.g. "1/5 failed"
    rank: int = 0  # 1 best, 2 second, 0 neither
    n: int = 0  # finished runs behind mean and std

    def value_text(self, pm: str) -> str:
        if math.isnan(self.mean):
            return "—" if pm == "±" else "--"
        text = f"{self.mean:.{self.digits}f}"
        if not math.isnan(self.std):
            text += f" {pm} {self.std:.{self.digits}f}"
        return text


@dataclass
class Table:
    title: str
    row_header: str
    columns: list[str]
    rows: list[tuple[str, list[Cell]]] = field(default_factory=list)
    label: str = ""


def _note(r: pd.Series) -> str:
    parts = []
    bad = int(r.n_failed)
    if bad:
        div = int(r.n_diverged)
        parts.append(f"{bad}/{int(r.n_runs)} failed" + (f", {div} diverged" if div else ""))
    if int(r.n_missing):
        parts.append(f"{int(r.n_missing)} missing")
    if int(r.n_running):
        parts.append(f"{int(r.n_running)} running")
    return "; ".join(parts)


def _cell(summary: pd.DataFrame, variant: str, scene: str, metric: str) -> Cell:
    sel = summary[(summary.variant == variant) & (summary.scene == scene) & (summary.metric == metric)]
    if sel.empty:
        return Cell(digits=decimals(metric))
    r = sel.iloc[0]
    return Cell(float(r["mean"]), float(r["std"]), decimals(metric), _note(r), n=int(r["n"]))


RANK_ALPHA = 0.05


def _better(a: list[Cell], b: list[Cell]) -> bool:
    """Whether the cells ``a`` (equal as printed) differ from ``b`` by Welch's t at RANK_ALPHA;
    True when the runs carry no spread to test with (a rank by the printed means alone)."""
    x, y = a[0], b[0]
    if x.n < 2 or y.n < 2 or math.isnan(x.std) or math.isnan(y.std):
        return True
    from scipy import stats

    with np.errstate(all="ignore"):
        p = stats.ttest_ind_from_stats(x.mean, x.std, x.n, y.mean, y.std, y.n, equal_var=False).pvalue
    return bool(p < RANK_ALPHA) if math.isfinite(p) else x.mean != y.mean


def rank_column(cells: list[Cell], lower_better: bool) -> None:
    """Mark the best (1) and second-best (2) distinct values as printed, each only when it is
    better than the next by Welch's t (p < 0.05) where the cells carry a spread: a column whose
    leaders are indistinguishable marks nothing. Ties share a rank."""
    shown = [round(c.mean, c.digits) for c in cells]
    values = sorted({v for v in shown if not math.isnan(v)}, reverse=not lower_better)
    finite = sum(not math.isnan(v) for v in shown)
    if finite < 2:
        return
    groups = [[c for c, v in zip(cells, shown) if v == value] for value in values]
    if len(groups) == 1 or not _better(groups[0], groups[1]):
        return
    for c in groups[0]:
        c.rank = 1
    if finite >= 3 and len(groups) > 1 and (len(groups) == 2 or _better(groups[1], groups[2])):
        for c in groups[1]:
            c.rank = 2


def _columns(scenes: list[str]) -> list[str]:
    return [*scenes, AVERAGE] if len(scenes) > 1 else scenes


def variants_x_scenes(summary: pd.DataFrame, metric: str, variants: list[str], scenes: list[str],
                      labels: dict[str, str], study: str, unranked: tuple[str, ...] = ()) -> Table:
    cols = _columns(scenes)
    table = Table(f"{pretty(metric)}", "Variant", [labels.get(c, c) for c in cols], label=f"tab:{study}-{metric}")
    grid = [[_cell(summary, v, c, metric) for c in cols] for v in variants]
    ranked = [row for v, row in zip(variants, grid) if v not in unranked]
    for j in range(len(cols)):
        rank_column([row[j] for row in ranked], lower_is_better(metric))
    table.rows = list(zip(variants, grid))
    return table


def metrics_x_scenes(summaries: dict[str, pd.DataFrame], variant: str, scenes: list[str],
                     labels: dict[str, str], study: str) -> Table:
    cols = _columns(scenes)
    table = Table(f"Metric conventions ({variant})", "Metric", [labels.get(c, c) for c in cols],
                  label=f"tab:{study}-conventions")
    table.rows = [(pretty(m), [_cell(s, variant, c, m) for c in cols]) for m, s in summaries.items()]
    return table


def variants_x_metrics(summaries: dict[str, pd.DataFrame], variants: list[str], scene: str, study: str) -> Table:
    metrics = list(summaries)
    table = Table("Speed and accuracy", "Variant", [pretty(m) for m in metrics], label=f"tab:{study}-metrics")
    grid = [[_cell(summaries[m], v, scene, m) for m in metrics] for v in variants]
    for j, m in enumerate(metrics):
        rank_column([row[j] for row in grid], lower_is_better(m))
    table.rows = list(zip(variants, grid))
    return table


# --- rendering ---------------------------------------------------------------------------


def to_markdown(table: Table) -> str:
    head = f"| {table.row_header} | " + " | ".join(table.columns) + " |"
    sep = "|---|" + "|".join(":---:" for _ in table.columns) + "|"
    lines = [head, sep]
    for name, cells in table.rows:
        out = []
        for c in cells:
            text = c.value_text("±")
            text = f"**{text}**" if c.rank == 1 else f"<u>{text}</u>" if c.rank == 2 else text
            out.append(text + (f" ({c.note})" if c.note else ""))
        lines.append(f"| {name} | " + " | ".join(out) + " |")
    return "\n".join(lines)


_LATEX_ESCAPES = {"\\": r"\textbackslash{}", "_": r"\_", "%": r"\%", "&": r"\&", "#": r"\#",
                  "$": r"\$", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\^{}",
                  "↑": r"$\uparrow$", "↓": r"$\downarrow$", "—": "--"}


def latex_escape(text: str) -> str:
    return "".join(_LATEX_ESCAPES.get(ch, ch) for ch in text)


def to_latex(table: Table, caption: str) -> str:
    """A ``table`` float with a booktabs ``tabular``; needs ``\\usepackage{booktabs}``.

    ``caption`` is LaTeX already (escape names with ``latex_escape``).
    """
    spec = "l" + "c" * len(table.columns)
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        rf"\caption{{{caption}}}",
        rf"\label{{{table.label}}}",
        rf"\begin{{tabular}}{{{spec}}}",
        r"\toprule",
        " & ".join(latex_escape(h) for h in [table.row_header, *table.columns]) + r" \\",
        r"\midrule",
    ]
    for name, cells in table.rows:
        out = []
        for c in cells:
            text = c.value_text(r"$\pm$")
            text = rf"\textbf{{{text}}}" if c.rank == 1 else rf"\underline{{{text}}}" if c.rank == 2 else text
            if c.note:
                text += rf" {{\scriptsize ({latex_escape(c.note)})}}"
            out.append(text)
        lines.append(" & ".join([latex_escape(name), *out]) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines)
