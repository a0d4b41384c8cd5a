"""The runner with the fake trainer: tracking layout, resume, failures, parallel runs, kill."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from conftest import HERE, TOY_STUDIES, prepare_workdir, use_fakes
from fakes import LOSS_STEPS, fake_generate, fake_train

from harness.run.lease import is_live
from harness.run.runner import run_study
from harness.spec.runs import Selection
from harness.tracking.records import load_runs, open_store


def _uri() -> str:
    return f"sqlite:///{Path('mlflow.db').resolve()}"
EXP = "ftgspp/toy"


def _run(sel: Selection, jobs: int = 1):
    return run_study("toy", sel, jobs=jobs, studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate,
                     echo=lambda s: None)


def _runs(kind: str = "run"):
    return load_runs(open_store(_uri()), EXP, "toy", kind=kind)


@pytest.fixture(scope="module")
def toy(tmp_path_factory: pytest.TempPathFactory, mlflow_template: Path):
    """The toy study run once (4 variants x 1 scene x 2 seeds), then run again."""
    mp = pytest.MonkeyPatch()
    try:
        work = prepare_workdir(tmp_path_factory.mktemp("toy"), mlflow_template, mp)
        first = _run(Selection())
        records_after_first = _runs()
        second = _run(Selection())
        yield {"work": work, "first": first, "second": second, "records": records_after_first, "mp": mp}
    finally:
        mp.undo()


def test_first_invocation_records_every_outcome(toy) -> None:
    first = toy["first"]
    assert (first.total, first.launched, first.finished, first.failed, first.diverged) == (8, 8, 4, 4, 2)
    by_variant: dict[str, list] = {}
    for rec in toy["records"]:
        by_variant.setdefault(rec.tags["variant"], []).append(rec)
    assert {v: sorted(r.status for r in recs) for v, recs in by_variant.items()} == {
        "baseline": ["FINISHED"] * 2, "cc": ["FINISHED"] * 2, "teleport": ["FAILED"] * 2, "wild": ["FAILED"] * 2}
    for rec in by_variant["teleport"]:
        assert rec.tags["failure"] == "input_error" and "strategy.relocation" in rec.tags["error"]
    for rec in by_variant["wild"]:
        assert rec.tags["failure"] == "diverged"


def test_child_runs_carry_tags_params_metrics_and_artifacts(toy) -> None:
    store = open_store(_uri())
    parents = _runs("study")
    rec = next(r for r in toy["records"] if r.tags["variant"] == "cc" and r.tags["seed"] == "1")
    for tag in ("study", "variant", "scene", "seed", "config_hash", "git_sha", "backend", "device", "profile"):
        assert rec.tags[tag], tag
    assert rec.tags["mlflow.parentRunId"] == parents[0].run_id
    assert rec.params["model.color_correction"] == "true" and rec.params["seed"] == "1"
    assert rec.params["data.path"] == "data/synth/easy"
    assert rec.metrics["psnr"] == pytest.approx(25.0 + 0.5 + 0.25 + 0.01 * 300 / 100 + 0.001 * 30)  # smoke: 300 G, 30 it
    history = store.client.get_metric_history(rec.run_id, "loss")
    assert [m.step for m in history] == list(range(LOSS_STEPS))
    files = {a.path for a in store.client.list_artifacts(rec.run_id)}
    assert "config.yaml" in files and "diagnostics" in files
    assert parents[0].tags["command"] == "study run toy --profile quick"
    assert json.loads(parents[0].tags["invocation"])["profile"] == "quick"


def test_rerun_picks_up_exactly_the_failed_runs(toy) -> None:
    second = toy["second"]
    assert (second.skipped, second.launched) == (4, 4)
    assert sorted(r["label"].split("/")[0] for r in second.results) == ["teleport", "teleport", "wild", "wild"]
    assert len(_runs("study")) == 2


def test_nothing_left_means_nothing_written(toy) -> None:
    before = len(_runs("study"))
    out = _run(Selection(variants=["baseline", "cc"]))
    assert (out.launched, out.skipped) == (0, 4)
    assert len(_runs("study")) == before, "no parent run for an invocation with nothing to do"


def test_status_and_report(toy, capsys: pytest.CaptureFixture[str]) -> None:
    use_fakes(toy["mp"])
    from harness.cli.study import main

    assert main(["status", "toy"]) == 0
    out = capsys.readouterr().out
    assert "total: 4 done, 4 failed, 0 missing" in out
    assert "failed seeds 0 (diverged), 1 (diverged)" in out
    stale = toy["work"] / "outputs" / "reports" / "toy" / "diagnostics" / "gone" / "easy" / "old.png"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"a diagnostic an earlier report copied")
    assert main(["report", "toy"]) == 0
    report = toy["work"] / "outputs" / "reports" / "toy"
    assert not stale.parent.parent.exists()  # a report from the store keeps only its own diagnostics
    for name in ("index.md", "table.md", "table.tex", "strip_psnr.png", "stability.png", "speed_accuracy.png", "runs.csv"):
        assert (report / name).is_file(), name
    assert (report / "diagnostics" / "cc" / "easy" / "lifetime_hist.png").is_file()
    index = (report / "index.md").read_text()
    assert "study run toy --profile quick" in index and "config_hash" in index
    table = (report / "table.md").read_text()
    assert "(2/2 failed, 2 diverged)" in table and "| cc | 25.69 ± 0.18 |" in table  # cc, seeds 0 and 1:
    # not bold: 2 seeds cannot tell it from the baseline (Welch p = 0.11)


def test_report_if_changed_skips_only_an_unchanged_report(toy, capsys: pytest.CaptureFixture[str]) -> None:
    use_fakes(toy["mp"])
    from harness.cli.study import main

    assert main(["report", "toy"]) == 0
    stamp = toy["work"] / "outputs" / "reports" / "toy" / ".fingerprint"
    made = stamp.stat().st_mtime_ns
    capsys.readouterr()
    assert main(["report", "--all", "--if-changed"]) == 0
    assert "toy: report up to date" in capsys.readouterr().out and stamp.stat().st_mtime_ns == made
    _run(Selection(variants=["baseline"], seeds=3))  # a new finished run: the report is stale
    assert main(["report", "toy", "--if-changed"]) == 0
    assert "report of" in capsys.readouterr().out and stamp.stat().st_mtime_ns != made
    with pytest.raises(SystemExit) as exc:  # a name and --all, or neither: one line, exit 2
        main(["report", "toy", "--all"])
    assert exc.value.code == 2


def test_the_report_stamp_covers_the_decision_over_every_study() -> None:
    """Another study's new runs can move this page's corrected p-values: the stamp changes with them."""
    import pandas as pd

    from harness.report.writer import fingerprint

    runs = pd.DataFrame({"variant": ["a"], "scene": ["s"], "seed": [0], "psnr": [30.0]})
    decided = pd.DataFrame({"id": ["c"], "verdict": ["inconclusive"], "p_adj": [0.20]})
    assert fingerprint(runs, decided) == fingerprint(runs, decided.copy())
    assert fingerprint(runs, decided) != fingerprint(runs, decided.assign(p_adj=0.03, verdict="reproduced"))
    assert fingerprint(runs, decided) != fingerprint(runs)


def test_crashed_and_killed_runs_are_failed_then_rerun(workdir: Path) -> None:
    sel = Selection(variants=["baseline"])
    Path("crash_seed1").write_text("")
    first = _run(sel)
    assert (first.finished, first.failed) == (1, 1)
    crashed = [r for r in _runs() if r.status == "FAILED"]
    assert len(crashed) == 1 and crashed[0].tags["failure"] == "crashed"
    assert "RuntimeError: simulated crash of seed 1" in crashed[0].tags["error"]
    # a run left RUNNING by a killed invocation: its last heartbeat is older than its lease
    store = open_store(_uri())
    exp = store.experiment_id(EXP)
    key_tags = {k: crashed[0].tags[k] for k in ("study", "variant", "scene", "seed", "config_hash")}
    stale = {"lease.owner": "node7:123", "lease.heartbeat": str(time.time() - 400), "lease.seconds": "300"}
    zombie = store.create_run(exp, "zombie", {**key_tags, "kind": "run", **stale})
    second = _run(sel)
    assert (second.launched, second.finished) == (1, 1)
    runs = {r.run_id: r for r in _runs()}
    assert runs[zombie].status == "FAILED" and runs[zombie].tags["failure"] == "interrupted"
    assert "lease expired" in runs[zombie].tags["error"] and "node7:123" in runs[zombie].tags["error"]
    finished = Counter(r.key for r in runs.values() if r.status == "FINISHED")
    assert len(finished) == 2 and set(finished.values()) == {1}
    taker = next(r for r in runs.values() if r.status == "FINISHED" and r.key == runs[zombie].key)
    assert taker.tags["lease.took_over"] == zombie


def test_only_the_first_seed_draws_figures_and_reports_show_the_lowest_seed_that_did(
        workdir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    Path("crash_seed0").write_text("")  # the first run of seed 0 (baseline's) crashes
    _run(Selection(variants=["baseline", "cc"], seeds=3))
    runs = _runs()
    for rec in runs:
        assert rec.params["diagnostics_figures"] == ("true" if rec.tags["seed"] == "0" else "false")
    assert {(r.tags["variant"], r.tags["seed"]) for r in runs if r.status == "FAILED"} == {("baseline", "0")}
    use_fakes(monkeypatch)
    from harness.cli.study import main

    assert main(["report", "toy"]) == 0
    diag = workdir / "outputs" / "reports" / "toy" / "diagnostics"
    assert (diag / "cc" / "easy" / "lifetime_hist.png").is_file()  # seed 0 finished: its figures
    # baseline's seed 0 crashed and later seeds draw none: nothing the study shows ("lifetime*")
    assert not (diag / "baseline").exists()


def test_parallel_jobs_lose_nothing_and_match_serial(toy, tmp_path: Path, mlflow_template: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    serial = {r.key: r.metrics for r in toy["records"] if r.status == "FINISHED"}
    prepare_workdir(tmp_path / "par", mlflow_template, monkeypatch)
    out = _run(Selection(variants=["baseline", "cc"], seeds=3), jobs=2)
    assert (out.launched, out.finished) == (6, 6)
    store = open_store(_uri())
    records = [r for r in _runs() if r.status == "FINISHED"]
    assert len(records) == 6 and len({r.key for r in records}) == 6
    for rec in records:
        assert len(store.client.get_metric_history(rec.run_id, "loss")) == LOSS_STEPS
        if rec.key in serial:
            assert rec.metrics == serial[rec.key]
    assert sum(rec.key in serial for rec in records) == 4


def test_sigkill_then_rerun_finishes_only_the_missing_runs(workdir: Path) -> None:
    env = {**os.environ, "FAKE_TRAIN_SLEEP": "1.5", "PYTHONPATH": str(HERE)}
    args = ["run", "toy", "--variants", "baseline,cc", "--seeds", "3", "--lease", "2"]
    proc = subprocess.Popen([sys.executable, str(HERE / "drive_study.py"), *args], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            done = sum(len(p.read_text().splitlines()) for p in Path("outputs").glob("studies/toy/*/progress.jsonl"))
            if done >= 2:
                break
            assert proc.poll() is None, "driver exited early"
            time.sleep(0.2)
        time.sleep(0.5)  # let the next run start
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    before = _runs()
    n_finished = sum(r.status == "FINISHED" for r in before)
    assert 2 <= n_finished < 6
    orphans = [r for r in before if r.status == "RUNNING"]
    assert len(orphans) == 1, "the killed run stays RUNNING: nobody may fail it while its lease is fresh"
    while any(is_live(r) for r in _runs() if r.status == "RUNNING"):  # its 2 s lease runs out
        time.sleep(0.2)
    out = _run(Selection(variants=["baseline", "cc"], seeds=3))
    assert out.launched == 6 - n_finished
    after = _runs()
    finished = Counter(r.key for r in after if r.status == "FINISHED")
    assert len(finished) == 6 and set(finished.values()) == {1}, "every run exactly once"
    assert all(r.status != "RUNNING" for r in after)
    orphan = next(r for r in after if r.run_id == orphans[0].run_id)
    assert orphan.status == "FAILED" and "lease expired" in orphan.error
