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


def test_gc_log_lines_from_a_real_process_are_summed_per_process(tmp_path: Path) -> None:
    import os
    import subprocess
    import sys

    rph = load()
    log = tmp_path / "gc.log"
    gclog = Path(rph.ROOT) / "benchmarks" / "gclog"
    code = "import gc\nfor _ in range(3): gc.collect()\ngc.collect(1)\n"
    env = {**os.environ, "PYTHONPATH": str(gclog), "FTGSPP_GC_LOG": str(log)}
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    (one,) = [p for p in rph.summarise_gc(log) if p["gen2"] >= 3]
    assert one["gen1"] >= 1 and one["gen2_s"] > 0.0
    before = log.read_text()
    env.pop("FTGSPP_GC_LOG")  # without the variable the module logs nothing
    subprocess.run([sys.executable, "-c", code], env=env, check=True, cwd=tmp_path)
    assert log.read_text() == before and sorted(p.name for p in tmp_path.iterdir()) == ["gc.log"]
    assert rph.summarise_gc(tmp_path / "absent.log") == []


def test_gc_summary_orders_processes_by_full_collection_seconds(tmp_path: Path) -> None:
    log = tmp_path / "gc.log"
    log.write_text("10 2 0.5 3\n11 2 0.1 0\n10 2 0.25 1\n11 1 0.01 0\n12 1 0.02 5\n12 2 0.")  # last line cut
    out = load().summarise_gc(log)
    assert [p["pid"] for p in out] == [10, 11, 12]
    assert out[0]["gen2"] == 2 and out[0]["gen2_s"] == pytest.approx(0.75)
    assert out[1]["gen1"] == 1 and out[2]["gen2"] == 0


def test_overrides_reach_every_run_of_the_benchmarks_study(tmp_path: Path) -> None:
    """``--override model=stg --override lr.scale=3`` times STGS as the studies train it."""
    from harness.spec.study_files import load_study

    (tmp_path / "rph.yaml").write_text(load().study_yaml(2, 4, "quick", "studio", ["model=stg", "lr.scale=3"]))
    spec = load_study("rph", studies_dir=tmp_path)
    assert list(spec.profiles["quick"].overrides) == ["profile=quick", "model=stg", "lr.scale=3"]
    assert spec.profiles["quick"].seeds == 4
