"""Read a study's runs back from the tracking store and match them to its plan.

Child runs carry ``kind=run`` and the tags ``study, profile, variant, scene, seed,
config_hash``; the parent run of each invocation carries ``kind=study`` and the
invocation (profile, seeds, scenes, variants, overrides) as JSON in ``invocation``.
Reading never creates a store: a SQLite file that does not exist means no runs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from harness.tracking.store import Store, check_reachable, resolve_uri, store_exists

RunKey = tuple[str, str, int, str]  # variant, scene, seed, config_hash (``PlannedRun.key``)


@dataclass
class RunRecord:
    """One child run as stored."""

    run_id: str
    status: str  # RUNNING | FINISHED | FAILED | KILLED
    tags: dict[str, str]
    metrics: dict[str, float] = field(default_factory=dict)
    params: dict[str, str] = field(default_factory=dict)
    start_time: int = 0
    artifact_uri: str = ""

    @property
    def key(self) -> RunKey:
        t = self.tags
        return (t.get("variant", ""), t.get("scene", ""), int(t.get("seed", -1)), t.get("config_hash", ""))

    @property
    def failure(self) -> str:
        return self.tags.get("failure", "")

    @property
    def error(self) -> str:
        return self.tags.get("error", "")


def experiment_name(base: str, study: str) -> str:
    """One MLflow experiment per study: ``ftgspp/secret5``."""
    return f"{base}/{study}"


def explicit_uri(overrides: list[str]) -> str | None:
    """The value of a ``tracking.uri=`` override, if the user gave one."""
    for o in overrides:
        if o.startswith("tracking.uri="):
            return o.split("=", 1)[1]
    return None


def tracking_target(overrides: list[str], params: dict[str, str], study: str) -> tuple[str, str]:
    """(tracking URI, MLflow experiment name) of an invocation with these ``overrides``, from
    the flattened config ``params`` of any of its runs."""
    uri = resolve_uri(explicit_uri(overrides), params["tracking.uri"])
    return uri, experiment_name(params["tracking.experiment"], study)


def _record(run: Any) -> RunRecord:
    return RunRecord(
        run_id=run.info.run_id,
        status=run.info.status,
        tags=dict(run.data.tags),
        metrics=dict(run.data.metrics),
        params=dict(run.data.params),
        start_time=int(run.info.start_time or 0),
        artifact_uri=run.info.artifact_uri or "",
    )


def open_store(uri: str) -> Store | None:
    """A store for reading, or None if the SQLite file does not exist; one line (``InputError``)
    for a server or database that does not answer."""
    if not store_exists(uri):
        return None
    check_reachable(uri)
    return Store(uri)


def load_runs(store: Store | None, experiment: str, study: str, kind: str = "run") -> list[RunRecord]:
    """All child runs (``kind='run'``) or parent runs (``kind='study'``) of a study, oldest first."""
    if store is None:
        return []
    exp_id = store.experiment_id(experiment, create=False)
    if exp_id is None:
        return []
    runs = store.search(exp_id, f"tags.study = '{study}' and tags.kind = '{kind}'")
    return sorted((_record(r) for r in runs), key=lambda r: r.start_time)


KEY_TAGS = ("study", "variant", "scene", "seed", "config_hash")


def find_key_runs(store: Store, experiment_id: str, tags: dict[str, str]) -> list[RunRecord]:
    """Every child run (any status) of the (study, variant, scene, seed, config_hash) in ``tags``."""
    def quoted(value: str) -> str:
        return "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"

    clauses = ["tags.kind = 'run'", *(f"tags.{k} = {quoted(tags[k])}" for k in KEY_TAGS)]
    runs = store.search(experiment_id, " and ".join(clauses))
    return sorted((_record(r) for r in runs), key=lambda r: r.start_time)


def latest_invocation(parents: list[RunRecord]) -> dict[str, Any] | None:
    """The invocation of the most recent parent run, if any."""
    for rec in reversed(parents):
        if "invocation" in rec.tags:
            return json.loads(rec.tags["invocation"])
    return None


def select(records: list[RunRecord], keys: list[RunKey]) -> dict[RunKey, RunRecord | None]:
    """For each planned run's key the record that counts: the latest FINISHED, else the latest attempt."""
    by_key: dict[RunKey, list[RunRecord]] = {}
    for rec in records:
        by_key.setdefault(rec.key, []).append(rec)
    chosen: dict[RunKey, RunRecord | None] = {}
    for key in keys:
        attempts = by_key.get(key, [])
        finished = [r for r in attempts if r.status == "FINISHED"]
        chosen[key] = (finished or attempts or [None])[-1]
    return chosen
