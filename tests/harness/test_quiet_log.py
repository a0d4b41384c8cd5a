"""A study run's terminal: the plan, a line per run as it starts and as it finishes, warnings,
the summary and the MLflow link - also when nothing is left to run. What else a run says (the
initialiser's INFO records, a training child's output, NumPy's RuntimeWarnings) and Hydra's
launcher lines go to log files in the study's output folder (``harness/run/runlog.py``)."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import HERE

from harness.run import runlog

RUNS = [f"{v}/easy/seed{s}" for v in ("baseline", "cc") for s in (0, 1)]
# every line a study run may print here, and nothing else
ALLOWED = [
    r"toy \(quick\): 4 runs = 2 variants x 1 scene x 2 seeds; \d already finished, \d to run",
    r"expected: .*",
    r"generating synthetic scene 'easy' into .*",
    r"outputs: outputs/studies/toy/[\w-]+/VARIANT/SCENE/SEED/, each run's log there: study_toy\.log",
    r"\[run\] (baseline|cc)/easy/seed\d: started \(child run \w{8}\)",
    r"\[run\] (baseline|cc)/easy/seed\d: WARNING: (child|in-process) warning, seed \d",
    r"\[\d/4\] (baseline|cc)/easy/seed\d: FINISHED psnr=[\d.]+ in \d+s \| study \d/4 runs done, .*",
    r"toy: 4 finished, 0 failed \(0 diverged\), 0 skipped; parent run \w+ in ftgspp/toy at .*",
    r"browse: /\S+/mlflow ui --backend-store-uri .*",  # the environment's mlflow, by its absolute path
]


def _study(*args: str) -> list[str]:
    """``study run toy ...`` in a process of its own (the fake trainer), its terminal's lines."""
    env = {**os.environ, "FAKE_TRAIN_NOISE": "1", "PYTHONPATH": str(HERE)}
    proc = subprocess.run([sys.executable, str(HERE / "drive_study.py"), "run", "toy", *args], env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return (proc.stdout + proc.stderr).splitlines()


@pytest.mark.slow
def test_a_study_run_prints_a_line_per_run_and_its_warnings_and_logs_the_rest(workdir: Path) -> None:
    lines = _study("--variants", "baseline,cc", "--seeds", "2")
    stray = [ln for ln in lines if not any(re.fullmatch(p, ln) for p in ALLOWED)]
    assert stray == [], "\n".join(lines)
    for run in RUNS:  # one line as it starts, one as it finishes, and its two warnings
        assert sum(ln.startswith(f"[run] {run}: started") for ln in lines) == 1
        assert sum(re.match(rf"\[\d/4\] {run}: FINISHED", ln) is not None for ln in lines) == 1
        assert sum(ln.startswith(f"[run] {run}: WARNING:") for ln in lines) == 2
    assert re.match(r"browse: /\S+/mlflow ui ", lines[-1])

    sweep = next(Path("outputs/studies/toy").iterdir())
    log = (sweep / "baseline/easy/seed0/study_toy.log").read_text()
    assert log.startswith("job #0: ")  # the run's overrides, as Hydra's launcher logs them
    for said in ("[ftgspp.init][INFO] - init: frame 0: 9 views", "frame 10: 9 views (child)", "train: 100%",
                 "child warning, seed 0", "in-process warning, seed 0", "RuntimeWarning: divide by zero"):
        assert said in log, said
    assert "#3 : " in (sweep / "launcher.log").read_text()

    again = _study("--variants", "baseline,cc", "--seeds", "2")  # nothing left: the plan and the link
    assert len(again) == 2 and "4 already finished, 0 to run" in again[0] and again[1].startswith("browse: ")


def test_capture_keeps_a_runs_output_in_its_log_and_passes_its_warnings_on(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    terminal = io.StringIO()
    monkeypatch.setattr(sys, "stdout", terminal)
    log = tmp_path / "run.log"
    with runlog.capture(log, "v/s/seed0", header="job #0: seed=0"):
        print("[2026-11-27 12:00:00,000][ftgspp.init][INFO] - init: frame 0")
        sys.stderr.write("train:  10%|#\rtrain: 100%|##########|\n[t][ftgspp.evaluate][WARNING] - no LPI")
        sys.stderr.write("PS weights\n[t][ftgspp.train][ERROR] - last line, unfinished")
    assert terminal.getvalue().splitlines() == ["[run] v/s/seed0: WARNING: no LPIPS weights",
                                                "[run] v/s/seed0: ERROR: last line, unfinished"]
    text = log.read_text()
    assert text.startswith("job #0: seed=0\n") and "init: frame 0" in text and "train: 100%" in text
    assert sys.stdout is terminal  # restored
