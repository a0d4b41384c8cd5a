"""The study's answer in MLflow: ``study report`` logs its verdicts and means on the parent run.

The parent run is the latest invocation whose child runs the report counts (else the latest
of the reported profile): the run that ``study run`` opened for them. It gets

- a tag ``verdict.<claim>`` per claim of ``claims.csv`` (``tracking.conventions.verdict_tags``),
  the claim's verdict as the report states it (``reproduced``, ``inconclusive``, ...); the
  verdict tags of claims the study no longer has are removed;
- the artifacts ``answer/verdicts.csv`` and ``answer/verdicts.md``: per claim its statement,
  comparison, effect and 95% CI at the metric's registry decimals, the SESOI, the p that
  decided it and the verdict; ``answer/means.csv`` and ``answer/means.md``: per variant the
  mean ± SD of the runs table's metrics (``conventions.VIEW_METRICS``) over the reported
  finished runs, at the registry's decimals (MLflow's runs table prints a group's mean with
  every digit JavaScript has: this is the rounded view of the same groups);
- its description (``mlflow.note.content``, Markdown on the run's Overview): the verdicts as a
  list, the means as a table, and the command that wrote them.

The experiment's description (plain text above the runs table) gets one more paragraph, the
verdicts in a line, until the next ``study run`` rewrites it. A report read from the committed
runs (no runs in the store) logs nothing; a store that refuses the writes costs one line.
"""

from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path
from typing import Callable

import pandas as pd

from harness.report import committed
from harness.report.claims_table import effect_text, p_decided_text, sesoi_text, verdict_text
from harness.report.fmt import num
from harness.report.results import ReportData
from harness.spec.metrics import decimals, label
from harness.tracking.conventions import (
    NOTE_TAG,
    VERDICT_TAG_PREFIX,
    VIEW_METRICS,
    experiment_note,
    run_link,
    verdict_tags,
)
from harness.tracking.records import RunRecord

ANSWER_DIR = "answer"  # the parent run's artifact folder
NOTE_MAX_CHARS = 4_000  # tracking.store.TAG_MAX_CHARS: a longer description would be cut mid-table
TEXT_COLUMNS = ("id", "statement", "comparison", "scope", "note", "raw_verdict", "interval_note", "detail",
                "registered_before_runs", "registration_note", "withdrawn")


def log_answer(data: ReportData, out: Path, echo: Callable[[str], None] = print) -> str | None:
    """Log the report in ``out`` (its ``claims.csv``) and the means of ``data`` on the reported
    parent run; returns its run id, None when nothing was logged."""
    parent = reported_parent(data)
    if parent is None or data.store is None or data.recorded is not None:
        return None
    claims = read_claims(out / "claims.csv")
    means = means_frame(data.df)
    stamp = f"`study report {data.study.name}` of {time.strftime('%Y-%m-%d %H:%M')}"
    try:
        exp_id = data.store.experiment_id(data.experiment, create=False) or ""  # there: it holds the parent
        _write(data, exp_id, parent, claims, means, stamp)
    except Exception as exc:  # the report's files are written: MLflow's copy is a convenience
        echo(f"{data.study.name}: verdicts not logged in MLflow ({type(exc).__name__}: {str(exc)[:200]})")
        return None
    echo(f"{data.study.name}: verdicts and means on parent run {parent.tags.get('mlflow.runName', parent.run_id)}:"
         f" {run_link(data.uri, exp_id, parent.run_id)}")
    return parent.run_id


def reported_parent(data: ReportData) -> RunRecord | None:
    """The latest parent run of the reported child runs, else of the reported profile."""
    ids = {rec.tags.get("mlflow.parentRunId") for rec in data.chosen.values() if rec is not None}
    mine = [p for p in data.parents if p.run_id in ids] or \
        [p for p in data.parents if p.tags.get("profile") == data.sel.profile]
    return mine[-1] if mine else None  # data.parents: oldest first


def read_claims(path: Path) -> pd.DataFrame:
    """``claims.csv`` as the report wrote it (an empty frame when the study has no claims)."""
    if not path.is_file():
        return pd.DataFrame()
    present = [c for c in TEXT_COLUMNS if c in pd.read_csv(path, nrows=0).columns]
    # text columns as text: an empty cell is "" (not NaN, which reads as true)
    return pd.read_csv(path, dtype={c: str for c in present}, keep_default_na=True).fillna(
        {c: "" for c in present})


def means_frame(df: pd.DataFrame, metrics: tuple[str, ...] = VIEW_METRICS) -> pd.DataFrame:
    """Per variant (in the report's order) the finished runs, and mean and SD of each of
    ``metrics`` the runs logged: what the study view's group rows average."""
    done = df[df.status == "FINISHED"]
    present = [m for m in metrics if m in done and done[m].notna().any()]
    rows = []
    for variant, runs in done.groupby("variant", sort=False):
        row: dict[str, object] = {"variant": variant, "runs": len(runs)}
        for m in present:
            row[f"{m}_mean"], row[f"{m}_sd"] = runs[m].mean(), runs[m].std(ddof=1)
        rows.append(row)
    frame = pd.DataFrame(rows)
    frame.attrs["metrics"] = present
    return frame


def verdicts_csv(claims: pd.DataFrame) -> pd.DataFrame:
    """One row per claim: the numbers at the metric's registry decimals, the p that decided it."""
    rows = []
    for _, r in claims.iterrows():
        d = 2 if r.test == "variance" else decimals(r.metric)
        rows.append({"claim": r.id, "verdict": r.verdict, "statement": r.statement, "metric": r.metric,
                     "comparison": r.comparison, "effect": _round(r.effect, d), "ci_low": _round(r.ci_low, d),
                     "ci_high": _round(r.ci_high, d), "sesoi": r.sesoi, "p_decided": p_decided_text(r),
                     "n": r.n, "family": r.get("family", "")})
    return pd.DataFrame(rows)


def means_csv(means: pd.DataFrame) -> pd.DataFrame:
    """``means_frame`` with each metric's mean and SD rounded to its registry decimals."""
    shown = means.copy()
    for m in means.attrs.get("metrics", []):
        for col in (f"{m}_mean", f"{m}_sd"):
            shown[col] = shown[col].map(lambda x, d=decimals(m): _round(float(x), d))
    return shown


def verdicts_markdown(claims: pd.DataFrame) -> str:
    lines = ["| Claim | Comparison (metric) | Effect [95% CI] | SESOI | p | Verdict |", "|---|---|---|---:|---|---|"]
    lines += [f"| **{r.id}**: {r.statement} | {r.comparison} (`{r.metric}`) | {effect_text(r)} | {sesoi_text(r)} |"
              f" {p_decided_text(r)} | {verdict_text(r)} |" for _, r in claims.iterrows()]
    return "\n".join(lines)


def means_markdown(means: pd.DataFrame) -> str:
    metrics = means.attrs.get("metrics", [])
    lines = ["| Variant | Runs | " + " | ".join(label(m) for m in metrics) + " |",
             "|---|---:|" + "---:|" * len(metrics)]
    for _, r in means.iterrows():
        cells = [f"{num(r[f'{m}_mean'], decimals(m))} ± {num(r[f'{m}_sd'], decimals(m))}" for m in metrics]
        lines.append(f"| {r.variant} | {r.runs} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def verdict_items(claims: pd.DataFrame) -> str:
    """The verdicts as a Markdown list (a run's Overview gives its description half the page:
    a list reads there, a wide table does not)."""
    return "\n".join(f"- **{r.id}**: {verdict_text(r)} — {r.comparison} (`{r.metric}`) {effect_text(r)},"
                     f" SESOI {sesoi_text(r)}, {p_decided_text(r)}" for _, r in claims.iterrows())


def run_note(data: ReportData, claims: pd.DataFrame, means: pd.DataFrame, stamp: str) -> str:
    """The parent run's description (Markdown): the verdicts, then the means, within the tag's
    length (the verdicts first; what does not fit is in the artifacts)."""
    said = ", ".join(f"{r.id} **{r.verdict}**" for _, r in claims.iterrows())
    head = (f"The answer of {stamp} ({data.sel.profile} profile)" + (f": {said}." if said else ".")
            + f" The tables: `{ANSWER_DIR}/` in Artifacts." + committed.filled_text(data))
    verdict_part = f"**Verdicts**\n\n{verdict_items(claims)}" if len(claims) else "This study states no claims."
    means_part = f"**Means ± SD of the reported runs**\n\n{means_markdown(means)}" if len(means) else ""
    for parts in ((head, verdict_part, means_part), (head, verdict_part), (head,)):
        note = "\n\n".join(p for p in parts if p)
        if len(note) <= NOTE_MAX_CHARS:
            return note
    return head[:NOTE_MAX_CHARS]


def verdict_line(claims: pd.DataFrame, profile: str, stamp: str) -> str:
    """The experiment description's paragraph: plain text, no Markdown syntax (see
    ``conventions.experiment_note``)."""
    said = "; ".join(f"{r.id} {r.verdict}" for _, r in claims.iterrows())
    return f"Verdicts of the {profile} runs ({stamp.replace('`', '')}): {said}."


def _round(x: float, digits: int) -> float:
    return x if not isinstance(x, float) or math.isnan(x) else round(x, digits)


def _write(data: ReportData, exp_id: str, parent: RunRecord, claims: pd.DataFrame, means: pd.DataFrame,
           stamp: str) -> None:
    """Tags and description of ``parent``, its ``answer/`` files, the experiment's verdict line."""
    store = data.store
    assert store is not None
    tags = verdict_tags(dict(zip(claims.id, claims.verdict))) if len(claims) else {}
    for key in [k for k in parent.tags if k.startswith(VERDICT_TAG_PREFIX) and k not in tags]:
        store.call(store.client.delete_tag, parent.run_id, key)  # a claim the study no longer has
    store.log_batch(parent.run_id, tags={**tags, NOTE_TAG: run_note(data, claims, means, stamp)})
    with tempfile.TemporaryDirectory(prefix="ftgspp-answer-") as tmp:
        folder = Path(tmp)
        files = []
        if len(claims):
            verdicts_csv(claims).to_csv(folder / "verdicts.csv", index=False)
            (folder / "verdicts.md").write_text(verdicts_markdown(claims) + "\n")
            files += ["verdicts.csv", "verdicts.md"]
        if len(means):
            means_csv(means).to_csv(folder / "means.csv", index=False)
            (folder / "means.md").write_text(means_markdown(means) + "\n")
            files += ["means.csv", "means.md"]
        for name in files:
            store.log_artifact(parent.run_id, folder / name, ANSWER_DIR)
    if exp_id and len(claims):
        note = experiment_note(data.study.question, f"study run {data.study.name} --profile {data.sel.profile}",
                               f"study report {data.study.name}")
        store.set_experiment_tags(exp_id, {NOTE_TAG: note + "\n\n" + verdict_line(claims, data.sel.profile, stamp)})
