"""The per-ISA before/after table's plumbing (the script itself runs real benchmarks)."""

from __future__ import annotations

from pathlib import Path

from bench_scripts import load_script


def load():
    return load_script("isa_table")


def fake(fwd_bwd: float, it: float) -> tuple[dict, dict]:
    render = {"backends": {"cpu": {"fwd_ms": fwd_bwd / 2, "fwd_bwd_ms": fwd_bwd}}, "yardstick": None,
              "stages": {"prepare": {"fused_ms": 2.0}, "ssim_loss": {"numba_ms": 0.8}}}
    return render, {"backends": {"cpu": {"ms_per_iter": it}}}


def test_a_child_gets_its_tree_its_cache_and_the_targets_isa_only(monkeypatch, tmp_path: Path) -> None:
    t = load()
    monkeypatch.setenv("NUMBA_CPU_NAME", "generic")  # the caller's own choices must not leak in
    monkeypatch.setenv("ATEN_CPU_CAPABILITY", "default")
    env = t.child_env(tmp_path / "tree", "host", tmp_path / "cache")
    assert env["PYTHONPATH"] == str(tmp_path / "tree") and env["NUMBA_CACHE_DIR"] == str(tmp_path / "cache")
    assert "NUMBA_CPU_NAME" not in env and "ATEN_CPU_CAPABILITY" not in env  # the host's own kernels
    env = t.child_env(tmp_path / "tree", "znver3", tmp_path / "cache")
    assert env["NUMBA_CPU_NAME"] == "znver3" and env["NUMBA_CPU_FEATURES"] == ""
    assert env["ATEN_CPU_CAPABILITY"] == "avx2"


def test_the_table_has_one_column_per_target_and_version_with_medians() -> None:
    t = load()
    results = {"isa": {"host": "AVX-512, torch AVX512", "haswell": "AVX2, torch AVX2"}, "runs": {
        "host": {"old": [fake(5.0, 8.0), fake(6.0, 9.0), fake(7.0, 10.0)], "new": [fake(3.0, 6.0)]},
        "haswell": {"old": [fake(7.0, 9.0)], "new": [fake(4.0, 7.0)]}}}
    lines = t.table(results, ["old", "new"], ["host", "haswell"]).splitlines()
    assert lines[0].count("|") == 6 and "haswell (AVX2, torch AVX2) new" in lines[0]
    fwd_bwd = next(line for line in lines if "fwd+bwd (ms)" in line and "render" in line)
    assert fwd_bwd.split("|")[2:6] == [" 6.00 ", " 3.00 ", " 7.00 ", " 4.00 "]  # medians, in column order
    assert next(line for line in lines if "yardstick" in line).count("–") == 4  # not measured: a dash
