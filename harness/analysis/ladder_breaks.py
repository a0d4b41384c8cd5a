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

Every run on a ladder gets one outcome, the first of these that fits (a failure *kind*, by
symptom, issue 46):

- ``crashed``: FAILED for any reason but divergence (crashes and input errors alike);
- ``diverged``: FAILED with failure ``diverged``: the trainer checks the loss every step and stops
  at the first non-finite value (a non-finite parameter of a drawn Gaussian makes the loss
  non-finite at that step);
- ``colour``: colour collapse, a finished run whose held-out gap between colour-aligned and raw
  PSNR (``psnr_cc - psnr``) exceeds the same cell's *reference gap* by more than ``COLOUR_DB`` =
  3 dB. The reference gap is the mean gap of the study's baseline variant (FreeTimeGS without
  colour correction, which has no colour transforms to drift) over its finished runs in that
  cell: the part of the gap the scene's own held-out colour shift explains. Baseline runs define
  it and are never colour-collapsed; a cell without finished baseline runs judges none;
- ``quality``: quality loss, a finished run whose colour-aligned PSNR (``psnr_cc``) is more than
  the metric's smallest effect of interest (``harness.spec.metrics.sesoi``: 0.2 dB) below the
  same variant's mean over its finished runs on the ladder's base cell. Base-cell runs define
  that reference and never lose quality; a component variant without base-cell runs uses the
  reference of the variant its name extends (``ftgspp_no_gate`` -> ``ftgspp``), and one with
  neither is not judged;
- ``ok``: any other finished run;
- ``not_run``: KILLED (interrupted by a person), RUNNING or MISSING; not counted as attempted.

Each kind's rate is its count over the attempted runs, with an exact (Clopper-Pearson) 95 %
interval from statsmodels. A rung *breaks* a method when it crashes, diverges or collapses its
colours (``BREAKS``); quality loss is the gentler kind, reported beside it. Variants that run
on every cell of a ladder (``StudyScene.variants``) are its ``method``\\ s; the others
(component ablations such as ``ftgspp_no_gate`` run on a few cells) are ``component`` rows,
tabulated per cell next to the methods. ``changing_rungs`` names the rungs where a method's rate
of some kind differs from the rung before it, the rungs a study gives more seeds.
``report.ladder_figures`` turns ``ladder_table`` into what ``study report`` shows
(``ladders.csv``, ``ladders.png`` and a Markdown section).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import pandas as pd
from statsmodels.stats.proportion import proportion_confint

from harness.spec.metrics import sesoi
from harness.spec.study_schema import StudyScene

METRIC = "psnr_cc"  # quality loss is judged on colour-aligned PSNR; raw PSNR mixes in the held-out colour
RAW = "psnr"
GAP = "psnr_cc_gap"  # psnr_cc - psnr, computed here when a run did not log it
COLOUR_DB = 3.0  # colour collapse: the gap this far above the cell's reference (baseline) gap
QUALITY_METRIC_SESOI = sesoi(METRIC)[0]  # 0.2 dB: quality loss
OK, CRASHED, DIVERGED, COLOUR, QUALITY, NOT_RUN = "ok", "crashed", "diverged", "colour", "quality", "not_run"
KINDS = (CRASHED, DIVERGED, COLOUR, QUALITY)  # every failure kind, in the order a run is tested
BREAKS = (CRASHED, DIVERGED, COLOUR)  # the kinds that break a method (quality loss is reported beside)
KIND_NAMES = {CRASHED: "crash", DIVERGED: "divergence", COLOUR: "colour collapse", QUALITY: "quality loss"}
METHOD, COMPONENT = "method", "component"
FAILURE_RULE = (
    "Each run gets one outcome, the first that fits: crash (FAILED for any reason but divergence);"
    " divergence (the loss became non-finite); colour collapse (finished, with a held-out gap between"
    f" colour-aligned and raw PSNR more than {COLOUR_DB:g} dB above the cell's reference gap, the mean gap"
    " of the study's baseline in the same cell, whose own runs define it and are never judged for it);"
    f" quality loss (finished, colour-aligned PSNR more than {QUALITY_METRIC_SESOI:g} dB, the metric's"
    " smallest effect of interest, below the same method's mean on the ladder's base cell); else ok."
    " Base-cell runs define the quality reference and never lose quality. Each rate is k of n attempted"
    " runs with its exact 95 % interval (Clopper-Pearson). A single run falls below the SESOI by seed"
    " noise too, so a rung's loss counts as *settled* only when the 95 % Welch interval of its mean"
    " minus the base cell's lies wholly below minus the SESOI. On ladders that change the scene"
    " (cameras, colour shift, motion speed) the base is an easier scene: a loss there is the scene's"
    " as much as the method's, so compare the methods' rows.")


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
    """The ladders the profile's cells form, in order of first mention, rungs in ladder order: of
    the scenes as written (instance 0; a ladder reads seeds of one scene, ``spec.instances``)."""
    scenes = [s for s in scenes if s.instance == 0]
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


def outcome(status: str, failure: str, quality: float, reference: float, gap: float = math.nan,
            reference_gap: float = math.nan) -> str:
    """One run's outcome (the module docstring's kinds, tested in order); a NaN reference (a
    base-cell run, or nothing to judge against) never makes a failure."""
    if status == "FAILED":
        return DIVERGED if failure == "diverged" else CRASHED
    if status != "FINISHED":
        return NOT_RUN
    if gap > reference_gap + COLOUR_DB:  # NaN on either side: not judged
        return COLOUR
    return QUALITY if quality < reference - QUALITY_METRIC_SESOI else OK


def _with_metrics(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with the quality metric, raw PSNR and the gap as columns (NaN where not logged)."""
    out = df.copy()
    if METRIC not in out and RAW in out:  # runs from before colour-aligned PSNR: judge the raw one
        out[METRIC] = out[RAW]
    for col in (METRIC, RAW):
        if col not in out:
            out[col] = math.nan
    computed = out[METRIC] - out[RAW]
    out[GAP] = out[GAP].fillna(computed) if GAP in out else computed
    return out


def _reference_variant(variant: str, have: set[str]) -> str:
    """``variant`` when it has base-cell runs, else the longest name it extends that has."""
    if variant in have:
        return variant
    parents = [k for k in have if variant.startswith(k + "_")]
    return max(parents, key=len) if parents else ""


def _references(df: pd.DataFrame, ladder: Ladder) -> dict[str, float]:
    """Per variant: mean colour-aligned PSNR of its finished runs on the ladder's base cell. A
    component variant without base-cell runs borrows the reference of the variant its name
    extends (``ftgspp_no_gate`` -> ``ftgspp``; the longest such prefix)."""
    base = df[(df.scene == ladder.base.scene.name) & (df.status == "FINISHED")]
    own = {str(v): float(g.mean()) for v, g in base.groupby("variant", sort=False)[METRIC]}
    named = {v: _reference_variant(v, set(own)) for v in dict.fromkeys(str(x) for x in df.variant)}
    return {v: own[ref] for v, ref in named.items() if ref}


def classify(df: pd.DataFrame, ladder: Ladder, baseline: str = "baseline") -> pd.DataFrame:
    """The runs of ``df`` on the ladder's cells with ``ladder``, ``rung``, ``step``,
    ``reference_psnr`` (quality reference), ``reference_gap`` (the baseline's mean gap in the
    cell) and ``outcome`` columns, in ladder order."""
    df = _with_metrics(df)
    refs = _references(df, ladder)
    parts = []
    for rung in ladder.rungs:
        runs = df[df.scene == rung.scene.name]
        ref = runs.variant.map(lambda v: refs.get(v, math.nan)).astype(float)
        base_gap = runs.loc[(runs.variant == baseline) & (runs.status == "FINISHED"), GAP].mean()
        ref_gap = pd.Series([math.nan if v == baseline else base_gap for v in runs.variant], index=runs.index,
                            dtype=float)
        outcomes = [outcome(r.status, str(r.failure), float(getattr(r, METRIC)), j if rung.step else math.nan,
                            float(getattr(r, GAP)), g)
                    for r, j, g in zip(runs.itertuples(), ref, ref_gap)]
        parts.append(runs.assign(ladder=ladder.name, rung=rung.value, step=rung.step,
                                 reference_psnr=ref, reference_gap=ref_gap, outcome=outcomes))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def classify_all(df: pd.DataFrame, scenes: Sequence[StudyScene], baseline: str = "baseline") -> pd.DataFrame:
    """``classify`` over every ladder: a run on the base cell appears once per ladder."""
    parts = [classify(df, lad, baseline) for lad in ladders_of(scenes)]
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame()


def role(variant: str, ladder: Ladder) -> str:
    """``method`` when the variant runs on every cell of the ladder, else ``component``."""
    every = all(not r.scene.variants or variant in r.scene.variants for r in ladder.rungs)
    return METHOD if every else COMPONENT


def rate_interval(k: int, n: int) -> tuple[float, float]:
    """Exact (Clopper-Pearson) 95 % interval of a rate of k in n; NaNs for n = 0."""
    if n == 0:
        return math.nan, math.nan
    low, high = proportion_confint(k, n, alpha=0.05, method="beta")
    return float(low), float(high)


def _stats(values: pd.Series, prefix: str) -> dict[str, float]:
    v = values.dropna()
    return {f"{prefix}_mean": float(v.mean()) if len(v) else math.nan,
            f"{prefix}_std": float(v.std(ddof=1)) if len(v) > 1 else math.nan}


def _cell(runs: pd.DataFrame) -> dict[str, object]:
    """Counts per outcome, each kind's rate with its interval and PSNR statistics of one
    (ladder, rung, variant)'s classified runs."""
    finished = runs[runs.status == "FINISHED"]
    n = {o: int((runs.outcome == o).sum()) for o in (OK, *KINDS, NOT_RUN)}
    attempted = len(runs) - n[NOT_RUN]
    row: dict[str, object] = {
        "n_attempted": attempted, "n_ok": n[OK], "n_finished": len(finished),
        **_stats(finished[METRIC], "psnr_cc"), **_stats(finished[RAW], "psnr"), **_stats(finished[GAP], "gap"),
        "reference_psnr": float(runs.reference_psnr.iloc[0]), "reference_gap": float(runs.reference_gap.iloc[0]),
        "n_not_run": n[NOT_RUN],
    }
    for kind in KINDS:
        lo, hi = rate_interval(n[kind], attempted)
        row.update({f"n_{kind}": n[kind], f"rate_{kind}": n[kind] / attempted if attempted else math.nan,
                    f"rate_{kind}_low": lo, f"rate_{kind}_high": hi})
    broken = sum(n[k] for k in BREAKS)
    lo, hi = rate_interval(broken, attempted)
    row.update({"n_broken": broken, "break_rate": broken / attempted if attempted else math.nan,
                "break_rate_low": lo, "break_rate_high": hi})
    return row


def settled_loss(cell: pd.Series, base: pd.Series) -> dict[str, float]:
    """The cell's colour-aligned PSNR minus the base cell's (the same variant's finished runs),
    with its 95 % Welch interval; ``loss_settled`` is 1.0 when the whole interval lies below
    minus the SESOI (a quality loss the runs resolve, not seed noise), 0.0 when it does not,
    NaN without two runs on each side."""
    from scipy import stats

    a, b = cell.dropna().to_numpy(float), base.dropna().to_numpy(float)
    out = {"loss_diff": float(a.mean() - b.mean()) if len(a) and len(b) else math.nan,
           "loss_diff_low": math.nan, "loss_diff_high": math.nan, "loss_settled": math.nan}
    if len(a) > 1 and len(b) > 1 and (a.std() > 0 or b.std() > 0):
        ci = stats.ttest_ind(a, b, equal_var=False).confidence_interval(0.95)
        out.update(loss_diff_low=float(ci.low), loss_diff_high=float(ci.high),
                   loss_settled=float(ci.high < -QUALITY_METRIC_SESOI))
    return out


def _first(rows: pd.DataFrame, column: str) -> float:
    """The first rung (``rows`` in ladder order) where ``column`` is above zero, else NaN."""
    hit = rows[rows[column] > 0]
    return float(hit.rung.iloc[0]) if len(hit) else math.nan


def ladder_table(df: pd.DataFrame, scenes: Sequence[StudyScene], baseline: str = "baseline") -> pd.DataFrame:
    """One row per (ladder, rung, variant) with runs: cell, role, counts and rates per failure
    kind with intervals, mean ± std colour-aligned and raw PSNR of finished runs, the cell's
    difference from the base cell with its Welch interval (``settled_loss``), and the variant's
    ``first_break`` (crash, divergence or colour collapse) and ``first_loss`` (the first rung
    whose loss is settled) rungs."""
    rows = []
    for lad in ladders_of(scenes):
        runs = classify(df, lad, baseline)
        if runs.empty:
            continue
        base = runs[(runs.step == 0) & (runs.status == "FINISHED")]
        for (step, v), sub in runs.groupby(["step", "variant"], sort=False):
            r = lad.rungs[int(step)]
            ref = base[base.variant == _reference_variant(str(v), set(base.variant))][METRIC]
            loss = settled_loss(sub.loc[sub.status == "FINISHED", METRIC], ref) if step else {}
            rows.append({"ladder": lad.name, "step": int(step), "rung": r.value, "scene": r.scene.name,
                         "scene_label": r.scene.title, "variant": v, "role": role(str(v), lad), **_cell(sub),
                         **loss})
    out = pd.DataFrame(rows)
    if out.empty:
        return out
    if "loss_settled" not in out:
        out["loss_settled"] = math.nan
    out["first_break"] = math.nan
    out["first_loss"] = math.nan
    for _, sub in out.groupby(["ladder", "variant"], sort=False):
        out.loc[sub.index, "first_break"] = _first(sub, "n_broken")
        out.loc[sub.index, "first_loss"] = _first(sub, "loss_settled")
    return out


def first_breaks(table: pd.DataFrame) -> pd.DataFrame:
    """Per (ladder, variant): the first rung, from the base, where some run broke (crash,
    divergence or colour collapse), and the first whose quality loss is settled (its Welch
    interval below minus the SESOI); ``text`` and ``loss_text`` name them or say "none up to
    <last rung with runs>"."""
    rows = []
    for (lad, v), sub in table.groupby(["ladder", "variant"], sort=False):
        tried = sub[sub.n_attempted > 0]
        texts = {}
        for col in ("first_break", "first_loss"):
            at = float(sub[col].iloc[0])
            if not math.isnan(at):
                b = sub[sub.rung == at].iloc[0]
                texts[col] = f"{lad} {b.rung:g} ({b.scene_label})"
            else:
                texts[col] = f"none up to {lad} {tried.rung.iloc[-1]:g}" if len(tried) else "no runs"
        at = float(sub.first_break.iloc[0])
        scene = "" if math.isnan(at) else str(sub[sub.rung == at].scene.iloc[0])
        rows.append({"ladder": lad, "variant": v, "role": sub.role.iloc[0], "first_break": at,
                     "first_loss": float(sub.first_loss.iloc[0]), "scene": scene, "text": texts["first_break"],
                     "loss_text": texts["first_loss"]})
    return pd.DataFrame(rows)


def changing_rungs(table: pd.DataFrame) -> pd.DataFrame:
    """The (ladder, rung, scene, variant) rows where a method's rate of some failure kind differs
    from its rate on the rung before it on the ladder: both rungs of each change are named."""
    keep = set()
    methods = table[table.role == METHOD]
    for _, sub in methods.groupby(["ladder", "variant"], sort=False):
        sub = sub[sub.n_attempted > 0].sort_values("step")  # a rung without runs has no rate to compare
        rates = sub[[f"rate_{k}" for k in KINDS]].fillna(-1).to_numpy()
        for i in range(1, len(sub)):
            if (rates[i] != rates[i - 1]).any():
                keep.update({sub.index[i - 1], sub.index[i]})
    return table.loc[sorted(keep), ["ladder", "rung", "scene", "variant", "n_attempted"]]


def cell_break_rates(df: pd.DataFrame, scenes: Sequence[StudyScene], baseline: str = "baseline") -> pd.DataFrame:
    """Per (variant, scene): the rate of runs that broke (``BREAKS``) and of quality losses, each
    run counted once (a base-cell run sits on every ladder with the same outcome)."""
    runs = classify_all(df, scenes, baseline)
    if runs.empty:
        return pd.DataFrame(columns=["variant", "scene", "break_rate", "quality_rate"])
    runs = runs.drop_duplicates(["variant", "scene", "seed"])
    tried = runs[runs.outcome != NOT_RUN]
    return (tried.groupby(["variant", "scene"], sort=False).outcome
            .agg(break_rate=lambda o: float(o.isin(BREAKS).mean()), quality_rate=lambda o: float((o == QUALITY).mean()))
            .reset_index())
