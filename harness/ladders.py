"""Stability ladders: along each difficulty ladder, where does each method first break?

A stability study's cells ("scenes") are rungs of ladders: ``rungs: {lr_scale: 3}`` in a
scene entry of the study file puts that cell on the ``lr_scale`` ladder at value 3
(``SceneSpec.rungs``). The base cell is a rung of every ladder (``rungs: {lr_scale: 1,
cameras: 10, colour_shift: 1, speed: 1}``) and is each ladder's first, easiest rung; the other
rungs follow in order of their distance from the base value. So a ladder may climb (lr_scale
1, 3, 10, 30) or descend (cameras 10, 6, 4, 3) without a table of directions; a ladder is
expected to leave its base in one direction. A ladder's base is its cell that belongs to the
most ladders (the first such cell in profile order), so a study without a shared base cell
still starts each ladder at its first-listed cell.

Every run on a ladder gets one outcome:

- ``crashed``: FAILED for any reason but divergence (crashes and input errors alike);
- ``diverged``: FAILED with failure ``diverged`` (the loss became NaN/Inf);
- ``collapsed``: FINISHED, but a collapse is a finished run that lost more than
  ``COLLAPSE_DB`` = 3 dB against the same method on the easiest rung, i.e. its PSNR is more
  than 3 dB below the same variant's mean PSNR over its finished runs on the ladder's base
  cell. Base-cell runs define that reference and are never collapsed; a component variant
  without base-cell runs uses the reference of the variant its name extends
  (``ftgspp_no_gate`` -> ``ftgspp``), and one with neither has no reference and no collapses;
- ``ok``: any other finished run;
- ``not_run``: KILLED (interrupted by a person), RUNNING or MISSING; not counted as attempted.

The failure rate of a rung is (crashed + diverged + collapsed) / attempted. Variants that run
on every cell of a ladder (``SceneSpec.variants``) are its ``method``\\ s; the others
(component ablations such as ``ftgspp_no_gate`` run on a few cells) are ``component`` rows,
tabulated per cell next to the methods. ``write`` makes everything ``study report`` shows:
``ladders.csv`` (``ladder_table``), ``ladders.png`` (``ladder_plot``) and the Markdown
section (``ladders_markdown``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from harness.plots import save_figure  # noqa: E402
from harness.studies import SceneSpec  # noqa: E402

METRIC = "psnr"
COLLAPSE_DB = 3.0  # a finished run more than this below its method's base-cell mean PSNR collapsed
LOG_X_LADDERS = ("lr_scale",)  # ladders whose rungs are multiplicative: plotted on a log axis
OK, CRASHED, DIVERGED, COLLAPSED, NOT_RUN = "ok", "crashed", "diverged", "collapsed", "not_run"
FAILURES = (CRASHED, DIVERGED, COLLAPSED)
METHOD, COMPONENT = "method", "component"
COLLAPSE_RULE = (f"A run fails if it crashed (FAILED for any reason but divergence), diverged (loss became"
                 f" NaN/Inf) or collapsed: a collapse is a finished run that lost more than {COLLAPSE_DB:g} dB"
                 f" against the same method on the easiest rung (its mean PSNR over finished base-cell runs);"
                 f" base-cell runs define that reference and are never collapsed.")


@dataclass(frozen=True)
class Rung:
    """One cell of a ladder at its rung value; ``step`` 0 is the base (easiest) rung."""

    value: float
    scene: SceneSpec
    step: int


@dataclass(frozen=True)
class Ladder:
    """A ladder's rungs in ladder order, base first."""

    name: str
    rungs: tuple[Rung, ...]

    @property
    def base(self) -> Rung:
        return self.rungs[0]

    @property
    def descending(self) -> bool:
        """True when the ladder gets harder as its value falls (cameras 10, 6, 4, 3)."""
        return self.rungs[-1].value < self.base.value


def ladders_of(scenes: Sequence[SceneSpec]) -> list[Ladder]:
    """The ladders the profile's cells form, in order of first mention, rungs in ladder order."""
    names = list(dict.fromkeys(name for s in scenes for name, _ in s.rungs))
    out = []
    for name in names:
        cells = [(s, dict(s.rungs)[name]) for s in scenes if name in dict(s.rungs)]
        base, base_value = max(cells, key=lambda c: len(c[0].rungs))  # first of the most shared
        order = sorted(range(len(cells)),
                       key=lambda i: (abs(cells[i][1] - base_value), cells[i][0] is not base, i))
        out.append(Ladder(name, tuple(Rung(cells[i][1], cells[i][0], k) for k, i in enumerate(order))))
    return out


def has_ladders(scenes: Sequence[SceneSpec]) -> bool:
    """True when any cell of the profile is a rung of a ladder."""
    return any(s.rungs for s in scenes)


def outcome(status: str, failure: str, psnr: float, reference: float) -> str:
    """One run's outcome; ``reference`` is NaN for base-cell runs (never collapsed)."""
    if status == "FAILED":
        return DIVERGED if failure == "diverged" else CRASHED
    if status != "FINISHED":
        return NOT_RUN
    return COLLAPSED if psnr < reference - COLLAPSE_DB else OK  # NaN on either side: ok


def _references(df: pd.DataFrame, ladder: Ladder) -> dict[str, float]:
    """Per variant: mean PSNR of its finished runs on the ladder's base cell. A component
    variant without base-cell runs borrows the reference of the variant its name extends
    (``ftgspp_no_gate`` -> ``ftgspp``; the longest such prefix)."""
    base = df[(df.scene == ladder.base.scene.name) & (df.status == "FINISHED")]
    refs = {str(v): float(g.mean()) for v, g in base.groupby("variant", sort=False)[METRIC]}
    for v in dict.fromkeys(str(x) for x in df.variant):
        parents = [k for k in refs if v.startswith(k + "_")]
        if v not in refs and parents:
            refs[v] = refs[max(parents, key=len)]
    return refs


def classify(df: pd.DataFrame, ladder: Ladder) -> pd.DataFrame:
    """The runs of ``df`` on the ladder's cells with ``ladder``, ``rung``, ``step``,
    ``reference_psnr`` and ``outcome`` columns, in ladder order."""
    if METRIC not in df:
        df = df.assign(**{METRIC: math.nan})
    refs = _references(df, ladder)
    parts = []
    for rung in ladder.rungs:
        runs = df[df.scene == rung.scene.name]
        ref = runs.variant.map(lambda v: refs.get(v, math.nan)).astype(float)
        outcomes = [outcome(r.status, str(r.failure), float(r.psnr), j if rung.step else math.nan)
                    for r, j in zip(runs.itertuples(), ref)]
        parts.append(runs.assign(ladder=ladder.name, rung=rung.value, step=rung.step,
                                 reference_psnr=ref, outcome=outcomes))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def classify_all(df: pd.DataFrame, scenes: Sequence[SceneSpec]) -> pd.DataFrame:
    """``classify`` over every ladder: a run on the base cell appears once per ladder."""
    parts = [classify(df, lad) for lad in ladders_of(scenes)]
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def role(variant: str, ladder: Ladder) -> str:
    """``method`` when the variant runs on every cell of the ladder, else ``component``."""
    every = all(not r.scene.variants or variant in r.scene.variants for r in ladder.rungs)
    return METHOD if every else COMPONENT


def _cell(runs: pd.DataFrame) -> dict[str, object]:
    """Counts and PSNR statistics of one (ladder, rung, variant)'s classified runs."""
    finished = runs.loc[runs.status == "FINISHED", METRIC].dropna()
    ok = runs.loc[runs.outcome == OK, METRIC].dropna()
    n = {o: int((runs.outcome == o).sum()) for o in (OK, *FAILURES, NOT_RUN)}
    attempted = len(runs) - n[NOT_RUN]
    return {
        "n_attempted": attempted, "n_ok": n[OK], "n_finished": int((runs.status == "FINISHED").sum()),
        "psnr_mean": float(finished.mean()) if len(finished) else math.nan,
        "psnr_std": float(finished.std(ddof=1)) if len(finished) > 1 else math.nan,
        "psnr_ok_mean": float(ok.mean()) if len(ok) else math.nan,
        "reference_psnr": float(runs.reference_psnr.iloc[0]),
        "n_crashed": n[CRASHED], "n_diverged": n[DIVERGED], "n_collapsed": n[COLLAPSED], "n_not_run": n[NOT_RUN],
        "failure_rate": sum(n[o] for o in FAILURES) / attempted if attempted else math.nan,
    }


def _first_break(rows: pd.DataFrame) -> float:
    """The first rung (``rows`` in ladder order) with a failure rate above zero, else NaN."""
    broken = rows[rows.failure_rate > 0]
    return float(broken.rung.iloc[0]) if len(broken) else math.nan


def ladder_table(df: pd.DataFrame, scenes: Sequence[SceneSpec]) -> pd.DataFrame:
    """One row per (ladder, rung, variant) with runs: cell, role, counts per outcome, mean ± std
    PSNR of finished runs, mean of ok runs, failure rate and the variant's ``first_break`` rung."""
    rows = []
    for lad in ladders_of(scenes):
        runs = classify(df, lad)
        if runs.empty:
            continue
        for (step, v), sub in runs.groupby(["step", "variant"], sort=False):
            r = lad.rungs[int(step)]
            rows.append({"ladder": lad.name, "step": int(step), "rung": r.value, "scene": r.scene.name,
                         "scene_label": r.scene.title, "variant": v, "role": role(str(v), lad), **_cell(sub)})
    out = pd.DataFrame(rows)
    if out.empty:
        return out
    out["first_break"] = math.nan
    for _, sub in out.groupby(["ladder", "variant"], sort=False):
        out.loc[sub.index, "first_break"] = _first_break(sub)
    return out


def first_breaks(table: pd.DataFrame) -> pd.DataFrame:
    """Per (ladder, variant): the first rung, from the base, whose failure rate is above zero;
    ``text`` names it or says "none up to <last rung with runs>"."""
    rows = []
    for (lad, v), sub in table.groupby(["ladder", "variant"], sort=False):
        tried = sub[sub.n_attempted > 0]
        at = float(sub.first_break.iloc[0])  # ladder_table's _first_break
        if not math.isnan(at):
            b = sub[sub.rung == at].iloc[0]
            text, scene = f"{lad} {b.rung:g} ({b.scene_label})", b.scene
        else:
            text, scene = (f"none up to {lad} {tried.rung.iloc[-1]:g}" if len(tried) else "no runs"), ""
        rows.append({"ladder": lad, "variant": v, "role": sub.role.iloc[0], "first_break": at,
                     "scene": scene, "text": text})
    return pd.DataFrame(rows)


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


def ladder_plot(table: pd.DataFrame, runs: pd.DataFrame, scenes: Sequence[SceneSpec],
                title: str, path: Path) -> Path:
    """One column per ladder: mean ± std PSNR (collapsed runs as hollow triangles) on top,
    failure rate with crashed/diverged/collapsed counts below; one line per method."""
    lads = ladders_of(scenes)
    fig, axes = plt.subplots(2, len(lads), figsize=(4.2 * len(lads), 7.0), squeeze=False, sharey="row",
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
    axes[0][0].legend(fontsize=7, loc="best")
    fig.suptitle(f"{title}\nfailed runs: crash(ed), div(erged), coll(apsed) = finished"
                 f" > {COLLAPSE_DB:g} dB below the method's base-cell mean")
    return save_figure(fig, path)


def write(df: pd.DataFrame, scenes: Sequence[SceneSpec], out: Path, title: str) -> str:
    """``ladders.csv`` and ``ladders.png`` under ``out``; returns the Markdown section."""
    table = ladder_table(df, scenes)
    table.to_csv(out / "ladders.csv", index=False)
    if table.empty:
        return ladders_markdown(table, pd.DataFrame())
    ladder_plot(table, classify_all(df, scenes), scenes, title, out / "ladders.png")
    return ladders_markdown(table, first_breaks(table), "ladders.png")
