"""Stability ladders: along each difficulty ladder, where does each method first break?

A stability study's cells ("scenes") are rungs of ladders: ``rungs: {lr_scale: 3}`` in a
scene entry of the study file puts that cell on the ``lr_scale`` ladder at value 3
(``StudyScene.rungs``). The base cell is a rung of every ladder (``rungs: {lr_scale: 1,
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
on every cell of a ladder (``StudyScene.variants``) are its ``method``\\ s; the others
(component ablations such as ``ftgspp_no_gate`` run on a few cells) are ``component`` rows,
tabulated per cell next to the methods. ``report.ladder_figures`` turns ``ladder_table`` into what
``study report`` shows (``ladders.csv``, ``ladders.png`` and a Markdown section).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import pandas as pd

from harness.spec.study_schema import StudyScene

METRIC = "psnr"
COLLAPSE_DB = 3.0  # a finished run more than this below its method's base-cell mean PSNR collapsed
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
    scene: StudyScene
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


def ladders_of(scenes: Sequence[StudyScene]) -> list[Ladder]:
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


def has_ladders(scenes: Sequence[StudyScene]) -> bool:
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


def classify_all(df: pd.DataFrame, scenes: Sequence[StudyScene]) -> pd.DataFrame:
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


def ladder_table(df: pd.DataFrame, scenes: Sequence[StudyScene]) -> pd.DataFrame:
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
