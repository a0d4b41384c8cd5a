"""``MlflowTracker``: the trainer's ``Tracker`` (``ftgspp.tracker``) for one MLflow child run.

Params go in batches of 100 (``log_batch``), step metrics are buffered and flushed in
batches, artifacts are uploaded as they come.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

from harness.tracking.store import METRICS_PER_BATCH, Store

FLUSH_SECONDS = 10.0


def metric_entities(metrics: dict[str, float], step: int) -> list[Any]:
    """MLflow ``Metric`` entities for numeric values (non-numbers are dropped)."""
    from mlflow.entities import Metric

    now = int(time.time() * 1000)
    out = []
    for key, value in metrics.items():
        try:
            v = float(value)
        except (TypeError, ValueError):
            continue
        out.append(Metric(key, v if not math.isinf(v) else math.copysign(1.7976931348623157e308, v), now, step))
    return out


class MlflowTracker:
    """``Tracker`` for one MLflow run; call ``flush()`` (or ``close()``) at the end."""

    def __init__(self, store: Store, run_id: str, flush_seconds: float = FLUSH_SECONDS) -> None:
        self.store = store
        self.run_id = run_id
        self.flush_seconds = flush_seconds
        self.params: dict[str, str] = {}
        self.logged_artifacts: set[Path] = set()
        self.metric_keys: set[str] = set()
        self._pending: list[Any] = []
        self._last_flush = time.monotonic()

    def log_params(self, params: dict[str, Any]) -> None:
        """Log new params; a key already logged with another value goes in as ``trainer/<key>``."""
        new: dict[str, str] = {}
        for key, value in params.items():
            text = str(value)
            if key in self.params and self.params[key] != text:
                key = f"trainer/{key}"
            if self.params.get(key) != text:
                new[key] = text
        self.params.update(new)
        if new:
            self.store.log_batch(self.run_id, params=new)

    def log_metrics(self, metrics: dict[str, float], step: int | None = None) -> None:
        entities = metric_entities(metrics, 0 if step is None else int(step))
        self.metric_keys.update(m.key for m in entities)
        self._pending.extend(entities)
        if len(self._pending) >= METRICS_PER_BATCH or time.monotonic() - self._last_flush > self.flush_seconds:
            self.flush()

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        path = Path(path)
        if not path.exists():
            return
        self.store.log_artifact(self.run_id, path, artifact_path)
        self.logged_artifacts.add(path.resolve())

    def set_tags(self, tags: dict[str, str]) -> None:
        self.store.log_batch(self.run_id, tags={k: str(v) for k, v in tags.items()})

    def flush(self) -> None:
        """Write buffered metrics."""
        pending, self._pending = self._pending, []
        if pending:
            self.store.log_batch(self.run_id, metrics=pending)
        self._last_flush = time.monotonic()

    close = flush
