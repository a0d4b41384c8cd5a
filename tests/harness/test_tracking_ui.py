"""The MLflow UI as a user opens it: the printed link selects the training-runs view and the
study's saved view, whose filter (run through MLflow's own search) keeps every training run
and no invocation parent, grouped by variant with the variant, scene and seed columns first;
the experiment carries a description that reads as plain text. (What the browser shows:
tests/cluster/cluster_ui.py.)"""

from __future__ import annotations

import json
import re
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import mlflow
import pytest
from conftest import TOY_STUDIES
from fakes import fake_generate, fake_train

from harness.run.runner import run_study
from harness.spec.runs import Selection
from harness.spec.study_files import load_study
from harness.tracking.conventions import NOTE_TAG, VIEW_KEY, VIEW_TAG_PREFIX, VIEW_TAGS, run_link, study_view, ui_link
from harness.tracking.records import open_store


def test_the_printed_link_opens_the_study_view_of_a_described_experiment(workdir: Path) -> None:
    lines: list[str] = []
    run_study("toy", Selection(), jobs=1, studies_dir=TOY_STUDIES, train_fn=fake_train, generate=fake_generate,
              echo=lines.append)
    uri = f"sqlite:///{Path('mlflow.db').resolve()}"
    store = open_store(uri)
    exp_id = store.experiment_id("ftgspp/toy", create=False)
    tags = store.client.get_experiment(exp_id).tags

    # the home page and the experiments list show the description verbatim: no markdown syntax
    note = tags[NOTE_TAG]
    question = " ".join(load_study("toy", TOY_STUDIES).question.split())
    assert note.startswith(question + "\n\n"), "the question first, on one line, as the lists cut it"
    assert "study run toy --profile quick" in note and "study report toy" in note
    assert not any(mark in note for mark in ("**", "`", "__")), note

    view = json.loads(tags[VIEW_TAG_PREFIX + VIEW_KEY])
    key_tags = ["tags.`variant`", "tags.`scene`", "tags.`seed`"]
    assert view["columnOrder"][:3] == key_tags and view["selectedColumns"] == view["columnOrder"]
    assert {"metrics.`psnr`", "metrics.`ssim1`", "metrics.`lpips_alex`"} <= set(view["columnOrder"][3:])
    assert set(view["columnWidths"]) <= set(view["columnOrder"])
    assert view["groupBy"] == {"aggregateFunction": "average",
                               "groupByKeys": [{"mode": "tag", "groupByData": "variant"}]}  # the UI's RunsGroupByConfig
    every = store.client.search_runs([exp_id])
    shown = store.client.search_runs([exp_id], filter_string=view["searchFilter"])
    parents = [r for r in every if "variant" not in r.data.tags]
    assert parents and len(shown) == len(every) - len(parents) > 0  # MLflow parses the filter; parents drop out
    assert all(set(VIEW_TAGS) <= set(r.data.tags) for r in shown), "every shown run fills the key columns"
    assert len({r.data.tags["variant"] for r in shown}) > 1, "the grouping has groups to show"

    browse = next(line for line in lines if line.startswith("browse: "))
    assert browse == f"browse: {ui_link(uri, exp_id)}"
    assert f"#/experiments/{exp_id}/runs?workflowType=machine_learning&viewStateShareKey={VIEW_KEY}" in browse
    assert browse.startswith(f"browse: mlflow ui --backend-store-uri {uri}, then http://127.0.0.1:5000/")
    # a filter or order in the URL (searchFilter, orderByKey, ...) would make the UI ignore the saved view
    query = parse_qs(urlsplit(urlsplit(browse.split(", then ")[1]).fragment).query)
    assert query == {"workflowType": ["machine_learning"], "viewStateShareKey": [VIEW_KEY]}


def test_links_to_a_server_are_direct() -> None:
    assert ui_link("http://tracking:5000/", "7") == (
        f"http://tracking:5000/#/experiments/7/runs?workflowType=machine_learning&viewStateShareKey={VIEW_KEY}")
    assert run_link("http://tracking:5000", "7", "abc") == (
        "http://tracking:5000/#/experiments/7/runs/abc?workflowType=machine_learning")


def _ui_key_lists() -> tuple[set[str], set[str]]:
    """(the run-table state a shared view may set, the search facets the URL may carry), as the
    installed MLflow UI's bundle lists them; empty where the bundle has no such list."""
    bundle = Path(mlflow.__file__).parent / "server" / "js" / "build" / "static" / "js"
    state: set[str] = set()
    facets: set[str] = set()
    for js in bundle.glob("*.js"):
        for names in re.findall(r'\[("(?:selectedColumns|searchFilter)"(?:,"[A-Za-z]+")+)\]', js.read_text(errors="replace")):
            keys = set(names.replace('"', "").split(","))
            if "runsPinned" in keys:
                state |= keys
            if "orderByKey" in keys:
                facets |= keys
    return state, facets


def test_the_installed_mlflow_ui_reads_every_key_of_the_study_view() -> None:
    state, facets = _ui_key_lists()
    if not (state and facets):
        pytest.skip(f"MLflow {mlflow.__version__}'s UI bundle lists no view keys this test can read")
    assert set(study_view()) <= state | facets, set(study_view()) - state - facets  # e.g. groupBy, columnOrder
    link_params = set(parse_qs(urlsplit(urlsplit(ui_link("http://h:5000", "1")).fragment).query))
    assert not link_params & facets, "a facet in the URL makes the UI ignore the shared view"
