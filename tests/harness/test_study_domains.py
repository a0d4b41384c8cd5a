"""Determinism domains in the harness: resume says when a finished run comes from another
domain, and ``study status`` / ``study report`` flag cells that mix domains."""

from __future__ import annotations

from pathlib import Path

from conftest import TOY_STUDIES, prepare_workdir, use_fakes
from fakes import fake_generate, fake_train

from harness.cli.study import main as study_main
from harness.report.writer import write_report
from harness.run.runner import run_study
from harness.spec.runs import Selection
from harness.tracking.records import load_runs, open_store


def test_foreign_domains_are_announced_on_resume_and_flagged_in_status_and_report(
        tmp_path: Path, mlflow_template: Path, monkeypatch, capsys) -> None:
    prepare_workdir(tmp_path, mlflow_template, monkeypatch)
    use_fakes(monkeypatch)
    sel = Selection(variants=["baseline"])
    lines: list[str] = []
    kw = dict(studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate)
    run_study("toy", sel, echo=lines.append, **kw)
    assert not [ln for ln in lines if ln.startswith("[resume]")], "same machine, same domain: nothing to say"
    store = open_store(f"sqlite:///{Path('mlflow.db').resolve()}")
    runs = load_runs(store, "ftgspp/toy", "toy")
    assert all(r.tags.get("determinism.id") for r in runs), "every run records its domain"
    store.client.set_tag(runs[0].run_id, "determinism.id", "0ther0ther")  # as if made on another machine
    lines.clear()
    out = run_study("toy", sel, echo=lines.append, **kw)
    notes = [ln for ln in lines if ln.startswith("[resume]")]
    assert out.launched == 0 and len(notes) == 1 and "0ther0ther" in notes[0] and "counted as done" in notes[0]
    capsys.readouterr()
    assert study_main(["status", "toy", "--variants", "baseline"]) == 0
    status = capsys.readouterr().out
    assert "MIXED determinism domains" in status and "0ther0ther" in status
    index = write_report("toy", sel, studies_dir=TOY_STUDIES, reports_root=tmp_path / "reports", echo=lambda s: None)
    text = index.read_text()
    assert "Runs from 2 determinism domains" in text and "mix runs of different domains: baseline/easy" in text


def test_a_run_of_a_worker_with_fewer_threads_is_compared_like_with_like(
        tmp_path: Path, mlflow_template: Path, monkeypatch) -> None:
    """A joblib worker trains with fewer torch threads than the plan assumed; its domain is that
    of this machine at that thread count, and resume must not call it foreign."""
    from ftgspp.runtime.determinism import expected_domain_id

    prepare_workdir(tmp_path, mlflow_template, monkeypatch)
    use_fakes(monkeypatch)
    sel = Selection(variants=["baseline"])
    kw = dict(studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate)
    run_study("toy", sel, echo=lambda s: None, **kw)
    store = open_store(f"sqlite:///{Path('mlflow.db').resolve()}")
    run = load_runs(store, "ftgspp/toy", "toy")[0]
    store.client.set_tag(run.run_id, "determinism.torch_threads", "7")
    store.client.set_tag(run.run_id, "determinism.id", expected_domain_id("default", 7, "native"))
    lines: list[str] = []
    run_study("toy", sel, echo=lines.append, **kw)
    assert not [ln for ln in lines if ln.startswith("[resume]")]


def test_rerun_stale_runs_again_what_another_trainer_made(tmp_path: Path, mlflow_template: Path, monkeypatch) -> None:
    from harness.tracking import provenance

    prepare_workdir(tmp_path, mlflow_template, monkeypatch)
    use_fakes(monkeypatch)
    sel = Selection(variants=["baseline"], seeds=1)
    kw = dict(studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate, echo=lambda s: None)
    assert run_study("toy", sel, **kw).launched == 1
    assert run_study("toy", sel, rerun_stale=True, **kw).launched == 0  # same trainer: current
    monkeypatch.setattr(provenance, "trainer_fingerprint", lambda root=None: "0ther0ther00")
    import harness.run.runner as runner

    monkeypatch.setattr(runner, "trainer_fingerprint", lambda: "0ther0ther00")
    assert run_study("toy", sel, **kw).launched == 0  # a plain resume keeps what it has
    out = run_study("toy", sel, rerun_stale=True, **kw)
    assert out.launched == 1 and out.finished == 1  # the code changed: run it again
