"""The first hour, as a new user has it: the demo's study in a fresh clone leaves the committed
answers alone, says whether it reproduced them, and a report of nothing is refused."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _study(clone: Path, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"}
    env["PYTHONPATH"] = str(clone)
    return subprocess.run([sys.executable, "-m", "harness.cli.study", *args], cwd=clone, env=env,
                          capture_output=True, text=True, timeout=1200)


@pytest.mark.slow
@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="needs the repository's git history to clone")
def test_the_demo_study_in_a_clone_checks_the_committed_answers_and_changes_none(tmp_path: Path) -> None:
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", "--no-hardlinks", str(ROOT), str(clone)], check=True)
    for path in ("ftgspp", "harness", "conf", "studies"):  # the code under test, committed or not
        shutil.rmtree(clone / path)
        # Numba's on-disk kernels come along (copy2 keeps the sources' mtimes, which is what the
        # cache checks), so the clone loads what this checkout compiled instead of compiling
        # for minutes again: compilation is not what this test is about (test_cpu_kernels is)
        shutil.copytree(ROOT / path, clone / path, ignore=shutil.ignore_patterns("*.pyc"))
    subprocess.run(["git", "-C", str(clone), "add", "-A", "ftgspp", "harness", "conf", "studies"], check=True)
    subprocess.run(["git", "-C", str(clone), "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "wip",
                    "--allow-empty"], check=True)

    empty = _study(clone, "report", "secret5")  # nothing has run yet
    assert empty.returncode == 2
    assert [ln for ln in empty.stderr.splitlines() if ln.strip()] == [empty.stderr.strip()]
    assert "no finished runs" in empty.stderr and not (clone / "outputs").exists()

    run = _study(clone, "run", "secret5", "--profile", "smoke", "--variants", "baseline")
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    assert _study(clone, "report", "secret5").returncode == 0
    assert _study(clone, "index").returncode == 0
    check = _study(clone, "check", "secret5")
    assert check.returncode == 0, check.stderr
    # the committed reference is the quick profile: these smoke runs share its cells but not its config
    assert "0/1 runs bit-identical to the committed report (reports/secret5/runs.csv)" in check.stdout
    assert "config (" in check.stdout
    assert (clone / "outputs/reports/secret5/index.md").is_file()
    changed = subprocess.run(["git", "-C", str(clone), "status", "--porcelain", "--", "reports"],
                             capture_output=True, text=True, check=True).stdout
    assert changed == "", f"the demo changed committed answers:\n{changed}"

    # against a report of the same runs: every run is bit-identical
    same = _study(clone, "check", "secret5", "--reference", "outputs/reports/secret5/runs.csv", "--strict")
    assert same.returncode == 0 and "1/1 runs bit-identical" in same.stdout, same.stdout
