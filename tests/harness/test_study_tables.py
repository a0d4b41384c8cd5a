"""Markdown/LaTeX tables: best and second-best marking, direction, compile-ready structure."""

from __future__ import annotations

import math
import re

import pandas as pd

from harness.report.tables import Cell, rank_column, to_latex, to_markdown, variants_x_scenes


def _summary(metric: str, means: dict[tuple[str, str], float]) -> pd.DataFrame:
    rows = []
    for (v, s), m in means.items():
        failed = 1 if math.isnan(m) else 0
        rows.append({"variant": v, "scene": s, "metric": metric, "n": 3 - failed * 3, "n_runs": 3,
                     "n_finished": 3 - 3 * failed, "n_failed": 3 * failed, "n_diverged": 3 * failed,
                     "n_running": 0, "n_missing": 0, "mean": m, "std": 0.1, "ci95": 0.2})
    return pd.DataFrame(rows)


MEANS = {("a", "s_1"): 30.0, ("b", "s_1"): 31.0, ("c", "s_1"): 30.5, ("d", "s_1"): math.nan,
         ("a", "average"): 29.0, ("b", "average"): 28.0, ("c", "average"): 28.5, ("d", "average"): math.nan}


def _table(metric: str = "psnr"):
    # two scenes -> an Average column; "s2" has no summary rows (all cells empty)
    return variants_x_scenes(_summary(metric, MEANS), metric, list("abcd"), ["s_1", "s2"], {"average": "Average"}, "demo")


def test_best_and_second_are_marked_per_column_in_markdown() -> None:
    md = to_markdown(_table("psnr"))
    rows = {line.split("|")[1].strip(): line for line in md.splitlines()[2:]}
    assert "**31.00 ± 0.10**" in rows["b"] and "<u>30.50 ± 0.10</u>" in rows["c"]
    assert "**29.00 ± 0.10**" in rows["a"] and "<u>28.50 ± 0.10</u>" in rows["c"]
    assert "3/3 failed, 3 diverged" in rows["d"]


def test_lower_is_better_metrics_flip_the_ranking() -> None:
    md = to_markdown(_table("lpips_alex"))
    rows = {line.split("|")[1].strip(): line for line in md.splitlines()[2:]}
    assert "**30.0000 ± 0.1000**" in rows["a"] and "**28.0000 ± 0.1000**" in rows["b"]


def test_ties_share_the_best_rank_and_two_rows_mark_no_second() -> None:
    cells = [Cell(1.0), Cell(1.0), Cell(0.5)]
    rank_column(cells, lower_better=False)
    assert [c.rank for c in cells] == [1, 1, 2]
    cells = [Cell(1.0), Cell(0.5)]
    rank_column(cells, lower_better=False)
    assert [c.rank for c in cells] == [1, 0]


def test_leaders_that_runs_cannot_tell_apart_are_not_marked() -> None:
    close = [Cell(30.0, 0.5, n=5), Cell(29.9, 0.5, n=5), Cell(28.0, 0.5, n=5)]  # Welch p = 0.76 for the leaders
    rank_column(close, lower_better=False)
    assert [c.rank for c in close] == [0, 0, 0]
    apart = [Cell(31.0, 0.1, n=5), Cell(29.9, 0.5, n=5), Cell(29.8, 0.5, n=5)]  # best clear, second not
    rank_column(apart, lower_better=False)
    assert [c.rank for c in apart] == [1, 0, 0]


def _balanced(text: str) -> bool:
    depth = 0
    for ch in re.sub(r"\\[{}]", "", text):
        depth += ch == "{"
        depth -= ch == "}"
        if depth < 0:
            return False
    return depth == 0


def test_latex_table_is_compile_ready() -> None:
    table = _table("psnr")
    tex = to_latex(table, r"demo: PSNR, mean $\pm$ std")
    assert _balanced(tex)
    assert tex.count(r"\begin{") == tex.count(r"\end{") == 2
    spec = re.search(r"\\begin\{tabular\}\{([lc]+)\}", tex).group(1)
    body = tex.split(r"\midrule")[1].split(r"\bottomrule")[0].strip().splitlines()
    header = tex.split(r"\toprule")[1].split(r"\midrule")[0].strip()
    for line in [header, *body]:
        assert line.endswith(r"\\")
        assert line.count("&") - line.count(r"\&") == len(spec) - 1
    assert r"s\_1" in header and r"\textbf{31.00 $\pm$ 0.10}" in tex and r"\underline{30.50 $\pm$ 0.10}" in tex
    assert tex.count("$") % 2 == 0

