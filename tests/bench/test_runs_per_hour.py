"""The runs-per-hour benchmark's arithmetic (the benchmark itself runs real studies)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "runs_per_hour.py"


def load():
    spec = importlib.util.spec_from_file_location("runs_per_hour", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_summary_splits_a_run_into_its_phases_and_the_rest() -> None:
    rph = load()
    phases = dict(init_seconds=2.0, train_seconds=30.0, eval_seconds=3.0, eval_lpips_seconds=1.0,
                  diagnostics_seconds=4.0)
    runs = [{"start": 100.0 + 10 * k, "end": 150.0 + 10 * k, **phases} for k in range(4)]  # 50 s each
    out = rph.summarise(wall_s=120.0, runs=runs, study_start=80.0)
    assert out["runs_per_hour"] == pytest.approx(4 * 3600 / 120)
    assert out["run_wall_s_median"] == 50.0 and out["rest_s_median"] == pytest.approx(10.0)
    assert out["phases_s_median"]["train_seconds"] == 30.0 and out["before_first_run_s"] == 20.0
