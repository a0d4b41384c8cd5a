"""The read side: a study's plan and runs as one per-run DataFrame, without running anything.

``collect(name, sel)`` loads the study file, plans the selection (the given one, else the
study's latest ``study run`` invocation, else the quick profile), reads the study's runs from
the tracking store once, picks for every planned run the attempt that counts (the latest
FINISHED, else the latest failed one: ``tracking.records.select``) and builds ``runs_frame``:
one row per planned run (missing ones included, status MISSING) with its status, failure,
determinism domain, metrics and key params. Reading never creates a store.
"""

from __future__ import annotations

import datetime
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from harness.analysis.aggregate import AVERAGE, DOMAIN_COLUMNS, EXTRA_PARAMS, KEY_COLUMNS
from harness.spec.metrics import add_differences
from harness.spec.plan import PlannedRun, RunKey, plan_runs
from harness.spec.runs import Selection, expand, standalone_command
from harness.spec.study_files import load_study
from harness.spec.study_schema import StudySpec
from harness.tracking.records import RunRecord, latest_invocation, load_runs, open_store, select, tracking_target
from harness.tracking.store import Store


FRESH = "@fresh"  # the column of a scene's fresh instances (``ReportData.shown``); ``@`` is never in a written name


@dataclass
class ReportData:
    """Everything a report is made from."""

    study: StudySpec
    sel: Selection
    planned: list[PlannedRun]
    df: pd.DataFrame
    uri: str
    experiment: str
    parents: list[RunRecord]
    store: Store | None
    chosen: dict[Any, RunRecord | None] = field(default_factory=dict)
    recorded: Recorded | None = None  # the runs come from a committed report's runs.csv (report.committed)
    filled: Filled | None = None  # some runs the store lacks come from it (report.committed.fill_missing)

    @property
    def baseline(self) -> str:
        """The baseline variant of the reported profile."""
        return self.study.profile(self.sel.profile).baseline

    def labels(self) -> dict[str, str]:
        """Scene name -> column title (``average`` -> "Average"; a scene's fresh instances shown
        together, ``shown``: "studio, 10 fresh instances")."""
        labels = {p.spec.scene.name: p.spec.scene.title for p in self.planned}
        if "instance" in self.df:
            fresh = self.df[self.df.instance > 0]
            for base, k in fresh.groupby("instance_of", sort=False).instance.nunique().items():
                labels[f"{base}{FRESH}"] = f"{labels.get(base, base)}, {k} fresh instances"
        labels[AVERAGE] = "Average"
        return labels

    def order(self) -> tuple[list[str], list[str]]:
        """(variants in profile order that have rows, scenes in plan order)."""
        prof = self.study.profile(self.sel.profile)
        variants = [v for v in prof.variants if v in set(self.df.variant)]
        return variants, list(dict.fromkeys(self.df.scene))

    def shown(self) -> pd.DataFrame:
        """The runs as the study page's tables and plots show them: the fresh instances of a scene
        (``spec.instances``: one run each) as one column, ``<scene>@fresh``, whose spread is the
        instances', beside the scene as written (the pilot's seeds). ``df`` itself when the study
        draws no instances."""
        return fresh_as_one(self.df)

    def shown_order(self) -> tuple[list[str], list[str]]:
        """``order`` of ``shown``: each scene as written, then its fresh instances' column."""
        variants, _ = self.order()
        return variants, list(dict.fromkeys(self.shown().scene))

    def trainer_fingerprints(self) -> list[str]:
        """The trainer fingerprints recorded by the finished runs ("unrecorded" for older runs)."""
        return trainer_fingerprints(self.df)

    def code_versions(self) -> list[str]:
        """The git commits recorded by the runs that count."""
        if self.recorded is not None:
            return list(self.recorded.code)
        found = {rec.tags.get("git_sha", "") for rec in self.chosen.values() if rec is not None}
        return sorted((found | set(self.filled.code if self.filled is not None else ())) - {""})

    def parent_ids(self) -> list[str]:
        """The study-level (parent) runs' ids, shortened to 8 characters."""
        if self.recorded is not None:
            return list(self.recorded.parents)
        return [p.run_id[:8] for p in self.parents]

    def invocations(self) -> list[str]:
        """The ``study run`` commands that made the reported profile's runs, each once."""
        if self.recorded is not None:
            return list(self.recorded.invocations)
        return list(dict.fromkeys(p.tags.get("command", "") for p in self.parents
                                  if p.tags.get("profile") == self.sel.profile and p.tags.get("command")))


@dataclass(frozen=True)
class Recorded:
    """What a committed report recorded of its runs beyond its ``runs.csv``: the provenance its
    page names (``report.committed`` reads it back when the tracking store has none of them)."""

    folder: Path  # reports/NAME: runs.csv, index.md, diagnostics/
    code: tuple[str, ...] = ()  # git commits ("code at ...")
    uri: str = ""  # the MLflow store and experiment that held the runs
    experiment: str = ""
    parents: tuple[str, ...] = ()  # parent run ids (8 characters)
    invocations: tuple[str, ...] = ()
    diagnostic_seeds: tuple[tuple[str, str, int], ...] = ()  # (variant, scene, seed) whose figures it shows


def fresh_as_one(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with each scene's fresh instances (``spec.instances``) named as one scene,
    ``<scene>@fresh``; ``df`` itself when it has none."""
    if "instance" not in df or not (df.instance > 0).any():
        return df
    fresh = df.instance > 0
    return df.assign(scene=df.scene.where(~fresh, df.instance_of.astype(str) + FRESH))


@dataclass(frozen=True)
class Filled:
    """Runs of the plan the tracking store lacks, read from the committed report in ``folder``
    (``report.committed.fill_missing``): their keys and the commits they were made at."""

    folder: Path  # reports/NAME
    keys: frozenset[RunKey]
    code: tuple[str, ...] = ()


def trainer_fingerprints(df: pd.DataFrame) -> list[str]:
    """The trainer fingerprints of ``df``'s finished runs; "unrecorded" for runs without one
    (an empty cell, or a ``runs.csv`` written before the column existed)."""
    done = df[df.status == "FINISHED"]
    col = done["trainer_fingerprint"] if "trainer_fingerprint" in done else pd.Series([""] * len(done))
    return sorted({str(f) if isinstance(f, str) and f else "unrecorded" for f in col})


def start_text(start_ms: int) -> str:
    """A run's MLflow start time (ms since the epoch) as UTC ISO 8601 to the millisecond, which
    sorts as it reads; "" when not recorded."""
    if not start_ms:
        return ""
    stamp = datetime.datetime.fromtimestamp(start_ms / 1000, tz=datetime.timezone.utc)
    return stamp.isoformat(timespec="milliseconds").replace("+00:00", "Z")


def runs_frame(chosen: dict[RunKey, RunRecord | None], planned: list[PlannedRun]) -> pd.DataFrame:
    """One row per planned run with its scene instance (``instance_of``, ``instance``:
    ``spec.instances``), status, failure, error, provenance (trainer fingerprint,
    model digest, the commit it was made from and when it started: ``git_sha``, ``start_time``,
    which ``spec.registration`` reads; determinism domain), metrics and key params."""
    rows = []
    for p in planned:
        rec = chosen.get(p.key)
        row: dict[str, object] = dict(zip(KEY_COLUMNS, p.key))
        row["scene_label"] = p.spec.scene.title
        row["instance_of"], row["instance"] = p.instance_of, p.instance  # from the study file, not tags
        for name in EXTRA_PARAMS:
            row[name] = float(p.params[name]) if name in p.params else math.nan
        if rec is None:
            row.update(status="MISSING", failure="", error="", run_id="", trainer_fingerprint="", model_digest="",
                       git_sha="", start_time="", command=standalone_command(p.spec))
        else:
            row.update(status=rec.status, failure=rec.failure, error=rec.error, run_id=rec.run_id,
                       trainer_fingerprint=rec.tags.get("trainer_fingerprint", ""),
                       git_sha=rec.tags.get("git_sha", ""), start_time=start_text(rec.start_time),
                       model_digest=rec.tags.get("model_digest", ""),
                       command=standalone_command(p.spec, rec.tags.get("determinism.torch_threads", "")))
            row.update({col: rec.tags.get(tag, "") for col, tag in DOMAIN_COLUMNS.items()})
            if rec.status == "FINISHED":
                row.update(rec.metrics)
        rows.append(row)
    return pd.DataFrame(rows)


def _invocation(inv: dict[str, Any]) -> Selection:
    return Selection(**{k: inv[k] for k in ("profile", "seeds", "scenes", "variants", "overrides")})


def _first_store(study: StudySpec, base: Selection,
                 specs: list) -> tuple[tuple[str, str], Store | None, list[RunRecord]]:
    """(tracking target, store, the study's invocations there) that the selection's first run names:
    only that run is planned."""
    target = tracking_target(base.overrides, plan_runs(specs[:1])[0].params, study.name)
    store = open_store(target[0])
    return target, store, load_runs(store, target[1], study.name, kind="study")


def store_has_runs(name: str, sel: Selection | None = None, studies_dir: Path | None = None) -> bool:
    """Whether the tracking store the selection's first run names holds any invocation or finished
    run of the study: when it holds neither, ``collect`` would plan every run (composing each config,
    most of ``study index``'s time) to find none."""
    study = load_study(name, studies_dir)
    base = sel or Selection()
    specs = expand(study, base)
    if not specs:
        return False
    (_, exp), store, parents = _first_store(study, base, specs)
    # an invocation may name another selection or store: collect follows it
    return bool(parents) or any(r.status == "FINISHED" for r in load_runs(store, exp, name))


def collect(name: str, sel: Selection | None = None, studies_dir: Path | None = None) -> ReportData:
    """Load the study, plan the selection to report and read its runs (read-only).

    Without ``sel``: the latest invocation's selection, else the quick profile. The store
    is found from the first run's config, so only the reported selection is planned in full.
    """
    study = load_study(name, studies_dir)
    base = sel or Selection()
    specs = expand(study, base)
    target, store, parents = _first_store(study, base, specs)
    inv = None if sel is not None else latest_invocation(parents)
    if inv is not None:
        base = _invocation(inv)
        specs = expand(study, base)
    planned = plan_runs(specs)
    if (final := tracking_target(base.overrides, planned[0].params, name)) != target:
        target, store = final, open_store(final[0])
        parents = load_runs(store, target[1], name, kind="study")
    uri, exp = target
    chosen = select(load_runs(store, exp, name), [p.key for p in planned])
    df = add_differences(runs_frame(chosen, planned))  # derived per-run metrics (the registry's differences)
    return ReportData(study, base, planned, df, uri, exp, parents, store, chosen)
