"""Which run's diagnostics a report copies: the lowest finished seed that drew figures."""

from __future__ import annotations

from types import SimpleNamespace

import pandas as pd

from harness.report.sections import _diagnostic_files


class _Store:
    def __init__(self, files: dict[str, list[str]]) -> None:
        self.files = files

    def artifact_files(self, run_id: str, path: str) -> list[str]:
        if run_id not in self.files:
            raise FileNotFoundError(run_id)  # as an artifact store with nothing logged there
        return self.files[run_id]


def _runs(*ids: str) -> pd.DataFrame:
    return pd.DataFrame({"run_id": list(ids), "seed": range(len(ids))})


def test_the_lowest_seed_with_a_figure_wins_over_lower_seeds_without() -> None:
    store = _Store({"a": ["diagnostics/diagnostics.json"],
                    "b": ["diagnostics/diagnostics.json", "diagnostics/xt_slice.png"],
                    "c": ["diagnostics/diagnostics.json", "diagnostics/velocity_map.png"]})
    run, files = _diagnostic_files(SimpleNamespace(store=store), _runs("a", "b", "c"), ["*"])
    assert run.run_id == "b" and files == ["diagnostics/diagnostics.json", "diagnostics/xt_slice.png"]


def test_without_any_figure_the_lowest_seed_with_a_matching_file_and_else_nothing() -> None:
    store = _Store({"b": ["diagnostics/diagnostics.json"], "c": ["diagnostics/diagnostics.json"]})
    run, files = _diagnostic_files(SimpleNamespace(store=store), _runs("a", "b", "c"), ["*"])
    assert run.run_id == "b" and files == ["diagnostics/diagnostics.json"]
    assert _diagnostic_files(SimpleNamespace(store=store), _runs("a", "b", "c"), ["*.png"]) is None
