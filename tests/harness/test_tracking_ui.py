"""The MLflow UI as a user opens it: the printed link selects the training-runs view and the
study's saved view, whose filter (run through MLflow's own search) keeps every training run
and no invocation parent; the experiment carries a description."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import TOY_STUDIES
from fakes import fake_generate, fake_train

from harness.run.runner import run_study
from harness.spec.runs import Selection
from harness.spec.study_files import load_study
from harness.tracking.conventions import NOTE_TAG, VIEW_KEY, VIEW_TAG_PREFIX, run_link, ui_link
from harness.tracking.records import open_store


def test_the_printed_link_opens_the_study_view_of_a_described_experiment(workdir: Path) -> None:
    lines: list[str] = []
    run_study("toy", Selection(), jobs=1, studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate,
              echo=lines.append)
    uri = f"sqlite:///{Path('mlflow.db').resolve()}"
    store = open_store(uri)
    exp_id = store.experiment_id("ftgspp/toy", create=False)
    tags = store.client.get_experiment(exp_id).tags

    question = " ".join(load_study("toy", TOY_STUDIES).question.split())
    assert question[:40] in " ".join(tags[NOTE_TAG].split())
    assert "`study run toy --profile quick`" in tags[NOTE_TAG] and "`study report toy`" in tags[NOTE_TAG]

    view = json.loads(tags[VIEW_TAG_PREFIX + VIEW_KEY])
    assert {"metrics.`psnr`", "metrics.`ssim1`", "metrics.`lpips_alex`", "tags.`variant`"} <= set(
        view["selectedColumns"])
    every = store.client.search_runs([exp_id])
    shown = store.client.search_runs([exp_id], filter_string=view["searchFilter"])
    parents = [r for r in every if "variant" not in r.data.tags]
    assert parents and len(shown) == len(every) - len(parents) > 0  # MLflow parses the filter; parents drop out

    browse = next(line for line in lines if line.startswith("browse: "))
    assert browse == f"browse: {ui_link(uri, exp_id)}"
    assert f"#/experiments/{exp_id}/runs?workflowType=machine_learning&viewStateShareKey={VIEW_KEY}" in browse
    assert browse.startswith(f"browse: mlflow ui --backend-store-uri {uri}, then http://127.0.0.1:5000/")


def test_links_to_a_server_are_direct() -> None:
    assert ui_link("http://tracking:5000/", "7") == (
        f"http://tracking:5000/#/experiments/7/runs?workflowType=machine_learning&viewStateShareKey={VIEW_KEY}")
    assert run_link("http://tracking:5000", "7", "abc") == (
        "http://tracking:5000/#/experiments/7/runs/abc?workflowType=machine_learning")
