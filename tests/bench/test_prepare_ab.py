"""benchmarks/prepare_ab.py: two versions exported from git side by side, alternating rounds, one
table of their cold compile and speed (the child processes are replaced here: they compile cold)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from bench_scripts import load_script

ab = load_script("prepare_ab")


@pytest.mark.skipif(not (ab.ROOT / ".git").exists(), reason="needs the repository's git history")
def test_a_revision_is_exported_with_its_own_kernels_and_the_working_tree_is_used_as_it_is(tmp_path: Path) -> None:
    assert ab.export(".", tmp_path / "x") == ab.ROOT
    path = ab.export("HEAD", tmp_path / "head")
    committed = subprocess.run(["git", "-C", str(ab.ROOT), "show", "HEAD:ftgspp/render/prepare_kernels.py"],
                               capture_output=True, text=True, check=True).stdout
    assert (path / "ftgspp/render/prepare_kernels.py").read_text() == committed
    assert not (path / "harness").exists()  # only the package under test


def test_versions_alternate_and_the_table_gives_each_one_and_their_ratio(monkeypatch, capsys) -> None:
    calls = []

    def fake(path, cache, method, n, k, threads):
        version = Path(cache).name.removeprefix("cache_")
        calls.append(version)
        head = version == "head"
        return {"first_forward_s": 10.0, "first_backward_s": 20.0 if head else 60.0, "forward_ms": 0.8,
                "backward_ms": 2.0 if head else 1.0}

    monkeypatch.setattr(ab, "child", fake)
    monkeypatch.setattr(ab, "export", lambda rev, into: Path(into))
    assert ab.main(["--base", "A", "--head", "B", "--rounds", "3"]) == 0
    assert calls == ["base", "head", "head", "base", "base", "head"]
    out = capsys.readouterr().out
    assert "cold compile, backward s" in out and "20.000" in out and "0.33x" in out
    assert "backward ms" in out and "2.00x" in out
