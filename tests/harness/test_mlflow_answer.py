"""``study report`` puts the study's answer in MLflow: on the parent run of the reported runs a
tag ``verdict.<claim>`` per claim (the report's verdict), the verdicts and the per-variant means
at the registry's decimals as artifacts and as the run's description, and the verdicts in the
experiment's description; runs made before the profile was in their names are still found,
skipped and reported (fake trainer)."""

from __future__ import annotations

import copy
from pathlib import Path

import pandas as pd
import pytest
import yaml
from fakes import MINI_STUDY, fake_generate, fake_train

from harness.report import families
from harness.report.writer import write_report
from harness.run.runner import run_study
from harness.spec.runs import Selection
from harness.tracking.conventions import NOTE_TAG, VERDICT_TAG_PREFIX, run_link
from harness.tracking.records import load_runs, open_store


@pytest.fixture
def mini(workdir: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The two-variant study of the fake trainer in a studies folder of its own."""
    import harness.spec.study_files

    studies = workdir / "studies"
    studies.mkdir()
    (studies / "mini.yaml").write_text(yaml.safe_dump(MINI_STUDY))
    monkeypatch.setattr(harness.spec.study_files, "STUDIES_DIR", studies)  # the index reads every study
    return studies


def _run(studies: Path, profile: str = "quick") -> None:
    run_study("mini", Selection(profile=profile), studies_dir=studies, train_fn=fake_train, generate=fake_generate,
              echo=lambda s: None)


def _report(studies: Path, profile: str = "quick") -> list[str]:
    lines: list[str] = []
    write_report("mini", Selection(profile=profile), studies_dir=studies, reports_root=Path("reports"),
                 echo=lines.append)
    return lines


def _artifact(store, run_id: str, name: str) -> Path:  # noqa: ANN001
    return Path(store.client.download_artifacts(run_id, f"answer/{name}", str(Path.cwd())))


def test_the_report_logs_its_verdicts_and_means_on_the_parent_run(mini: Path) -> None:
    _run(mini)
    lines = _report(mini)
    uri = f"sqlite:///{Path('mlflow.db').resolve()}"
    store = open_store(uri)
    (parent,) = load_runs(store, "ftgspp/mini", "mini", kind="study")
    claims = pd.read_csv("reports/mini/claims.csv")
    tags = store.client.get_run(parent.run_id).data.tags

    # a tag per claim, the report's verdict
    verdicts = {k.removeprefix(VERDICT_TAG_PREFIX): v for k, v in tags.items() if k.startswith(VERDICT_TAG_PREFIX)}
    assert verdicts == dict(zip(claims.id, claims.verdict)) and len(verdicts) == 4
    # the table artifacts: the same claims and verdicts, the effect at the metric's decimals (psnr: 2)
    table = pd.read_csv(_artifact(store, parent.run_id, "verdicts.csv"))
    assert list(table.claim) == list(claims.id) and list(table.verdict) == list(claims.verdict)
    cc = table.set_index("claim").loc["cc_mean"]
    assert cc.effect == round(claims.set_index("id").effect["cc_mean"], 2) == pytest.approx(0.5)
    assert "| **cc_mean**" in _artifact(store, parent.run_id, "verdicts.md").read_text()
    # the means a group row of the runs table shows, at the registry's decimals
    means = pd.read_csv(_artifact(store, parent.run_id, "means.csv")).set_index("variant")
    runs = pd.read_csv("reports/mini/runs.csv")
    for variant in ("baseline", "cc"):
        psnr = runs[runs.variant == variant].psnr
        assert means.runs[variant] == 3 and means.psnr_mean[variant] == round(psnr.mean(), 2)
        assert means.ssim1_mean[variant] == round(runs[runs.variant == variant].ssim1.mean(), 4)
    assert f"{runs[runs.variant == 'cc'].psnr.mean():.2f} ± " in _artifact(store, parent.run_id, "means.md").read_text()
    # the run's description: both tables (Markdown on the run's Overview)
    note = tags[NOTE_TAG]
    assert "- **cc_mean**: " in note and "| cc | 3 |" in note and "quick profile" in note
    # the experiment's description: the verdicts in a line, plain text
    exp = store.client.get_experiment_by_name("ftgspp/mini")
    last = exp.tags[NOTE_TAG].split("\n\n")[-1]
    assert last.startswith("Verdicts of the quick runs (study report mini of ") and "cc_mean " in last
    assert not any(mark in exp.tags[NOTE_TAG] for mark in ("**", "`", "__"))
    # the report says where: the parent's page in the training view
    assert lines[-1].endswith(run_link(uri, exp.experiment_id, parent.run_id))
    assert "workflowType=machine_learning" in lines[-1]

    # a claim the study no longer states loses its tag at the next report
    study = copy.deepcopy(MINI_STUDY)
    study["claims"] = [c for c in study["claims"] if c["id"] != "motion"]
    (mini / "mini.yaml").write_text(yaml.safe_dump(study))
    families.forget()  # the decision over every study is cached per process
    _report(mini)
    tags = store.client.get_run(parent.run_id).data.tags
    assert sorted(k for k in tags if k.startswith(VERDICT_TAG_PREFIX)) == [
        "verdict.cc_mean", "verdict.cc_spread", "verdict.psnr_ssim"]


def test_each_profile_reports_on_its_own_parent_run(mini: Path) -> None:
    _run(mini)
    _run(mini, "smoke")
    _report(mini, "smoke")
    store = open_store(f"sqlite:///{Path('mlflow.db').resolve()}")
    quick, smoke = load_runs(store, "ftgspp/mini", "mini", kind="study")
    assert (quick.tags["profile"], smoke.tags["profile"]) == ("quick", "smoke")
    assert any(k.startswith(VERDICT_TAG_PREFIX) for k in store.client.get_run(smoke.run_id).data.tags)
    assert not any(k.startswith(VERDICT_TAG_PREFIX) for k in store.client.get_run(quick.run_id).data.tags)
    assert "smoke profile" in store.client.get_run(smoke.run_id).data.tags[NOTE_TAG]


def test_runs_named_before_the_profile_was_in_names_are_still_found(mini: Path) -> None:
    """Older runs: named ``variant/scene/seed<k>``, some without a ``profile`` tag. They are found
    by their key tags (study, variant, scene, seed, config_hash): skipped, reported, answered."""
    _run(mini)
    store = open_store(f"sqlite:///{Path('mlflow.db').resolve()}")
    children = load_runs(store, "ftgspp/mini", "mini")
    for i, rec in enumerate(children):
        label = f"{rec.tags['variant']}/{rec.tags['scene']}/seed{rec.tags['seed']}"
        store.client.set_tag(rec.run_id, "mlflow.runName", label)
        if i % 2:
            store.client.delete_tag(rec.run_id, "profile")
    lines: list[str] = []
    out = run_study("mini", Selection(), studies_dir=mini, train_fn=fake_train, generate=fake_generate,
                    echo=lines.append)
    assert (out.launched, out.skipped) == (0, 6), lines
    _report(mini)
    runs = pd.read_csv("reports/mini/runs.csv")
    assert (runs.status == "FINISHED").all() and len(runs) == 6
    (parent,) = load_runs(store, "ftgspp/mini", "mini", kind="study")
    assert store.client.get_run(parent.run_id).data.tags["verdict.cc_mean"] == \
        pd.read_csv("reports/mini/claims.csv").set_index("id").verdict["cc_mean"]
