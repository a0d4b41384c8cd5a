"""The tracker protocol the trainer logs through, and its null object.

``ftgspp`` never imports mlflow: the harness passes an object with these methods
(``harness/tracking/mlflow_tracker.py`` wraps an ``MlflowClient``). Without one, ``NullTracker`` swallows
everything, so the trainer has no ``if tracking:`` branches.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol


class Tracker(Protocol):
    """What the trainer needs from experiment tracking."""

    def log_params(self, params: dict[str, Any]) -> None: ...

    def log_metrics(self, metrics: dict[str, float], step: int | None = None) -> None: ...

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None: ...

    def set_tags(self, tags: dict[str, str]) -> None: ...


class NullTracker:
    """A tracker that records nothing."""

    def log_params(self, params: dict[str, Any]) -> None:
        pass

    def log_metrics(self, metrics: dict[str, float], step: int | None = None) -> None:
        pass

    def log_artifact(self, path: str | Path, artifact_path: str | None = None) -> None:
        pass

    def set_tags(self, tags: dict[str, str]) -> None:
        pass


@dataclass
class RunResult:
    """Outcome of one training run.

    ``status`` is ``"FINISHED"`` or ``"FAILED"``; ``failure`` names why it failed
    (``"diverged"`` for a NaN/Inf loss), empty otherwise.
    """

    status: str
    metrics: dict[str, float] = field(default_factory=dict)
    failure: str = ""
    out_dir: Path | None = None
    artifacts: list[Path] = field(default_factory=list)
