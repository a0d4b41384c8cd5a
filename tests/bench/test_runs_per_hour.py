"""The benchmark scripts' arithmetic and input checks (the benchmarks themselves run real studies and runs)."""

from __future__ import annotations

from pathlib import Path

import pytest
from bench_scripts import load_script


def load():
    return load_script("runs_per_hour")


def test_summary_splits_a_run_into_its_phases_and_the_rest() -> None:
    rph = load()
    phases = dict(init_seconds=2.0, train_seconds=30.0, eval_seconds=3.0, eval_lpips_seconds=1.0,
                  diagnostics_seconds=4.0)
    runs = [{"start": 100.0 + 10 * k, "end": 150.0 + 10 * k, **phases} for k in range(4)]  # 50 s each
    out = rph.summarise(wall_s=120.0, runs=runs, study_start=80.0)
    assert out["runs_per_hour"] == pytest.approx(4 * 3600 / 120)
    assert out["run_wall_s_median"] == 50.0 and out["rest_s_median"] == pytest.approx(10.0)
    assert out["phases_s_median"]["train_seconds"] == 30.0 and out["before_first_run_s"] == 20.0
    # ends 150, 160, 170, 180: after the 2nd end (160) two more runs in 20 s
    assert out["steady_runs_per_hour"] == pytest.approx(2 * 3600 / 20)
    assert rph.summarise(wall_s=120.0, runs=runs[:2], study_start=80.0)["steady_runs_per_hour"] is None


def test_the_steady_rate_leaves_out_each_workers_first_run() -> None:
    rph = load()
    # two workers; their first runs take 40 s (start-up), later ones 30 s: 4 runs after t = 40
    ends = [40.0, 40.0, 70.0, 70.0, 100.0, 100.0]
    runs = [{"start": e - (40.0 if e == 40.0 else 30.0), "end": e} for e in ends]
    out = rph.summarise(wall_s=105.0, runs=runs, study_start=0.0, jobs=2)
    assert out["steady_runs_per_hour"] == pytest.approx(4 * 3600 / 60)  # 240 = 2 runs per 30 s
    assert out["runs_per_hour"] == pytest.approx(6 * 3600 / 105)


def test_a_target_compiles_for_its_cpu_in_its_own_cache_and_caps_torch(tmp_path: Path) -> None:
    env = load().target_environment("haswell", tmp_path / "cache")
    assert env["NUMBA_CPU_NAME"] == "haswell" and env["NUMBA_CPU_FEATURES"] == ""  # the target's own features
    assert env["NUMBA_CACHE_DIR"] == str(tmp_path / "cache")
    assert env["ATEN_CPU_CAPABILITY"] == "avx2" and env["ONEDNN_MAX_CPU_ISA"] == "AVX2"


def test_an_unknown_target_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert load().main(["--target", "pentium-mmx"]) == 2  # refused before any study starts
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown CPU target" in err[0]


def test_raster_views_refuses_a_folder_that_is_not_a_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert load_script("raster_views").main([str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a finished training run" in err[0]
