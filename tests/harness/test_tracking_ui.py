"""The MLflow UI as a user opens it: the printed link selects the training-runs view and the
study's saved view, whose filter (run through MLflow's own search) keeps every training run
and no invocation parent, grouped by profile and variant with the profile, variant, scene and
seed columns first; the experiment carries a description that reads as plain text; the
printed command names the environment's ``mlflow`` by its absolute path. (What the browser
shows: tests/cluster/cluster_ui.py.)"""

from __future__ import annotations

import json
import os
import re
import shlex
import sys
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import mlflow
import pytest
from conftest import TOY_STUDIES
from fakes import fake_generate, fake_train

from harness.run.runner import run_study
from harness.spec.runs import Selection
from harness.spec.study_files import load_study
from harness.tracking.conventions import (
    NOTE_TAG,
    VIEW_KEY,
    VIEW_TAG_PREFIX,
    VIEW_TAGS,
    browse_command,
    run_link,
    study_view,
    ui_link,
)
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
    key_tags = ["tags.`profile`", "tags.`variant`", "tags.`scene`", "tags.`seed`"]
    # the run name (only to size it: the UI sizes the columns the order names), then the key tags
    assert view["columnOrder"][:5] == ["attributes.`Run Name`", *key_tags]
    assert view["selectedColumns"] == view["columnOrder"][1:]
    assert {"metrics.`psnr`", "metrics.`ssim1`", "metrics.`lpips_alex`"} <= set(view["columnOrder"][5:])
    assert set(view["columnWidths"]) <= set(view["columnOrder"])
    assert view["groupBy"] == {"aggregateFunction": "average",  # the UI's RunsGroupByConfig: a group per
                               "groupByKeys": [{"mode": "tag", "groupByData": "profile"},  # (profile, variant)
                                               {"mode": "tag", "groupByData": "variant"}]}
    every = store.client.search_runs([exp_id])
    shown = store.client.search_runs([exp_id], filter_string=view["searchFilter"])
    parents = [r for r in every if "variant" not in r.data.tags]
    assert parents and len(shown) == len(every) - len(parents) > 0  # MLflow parses the filter; parents drop out
    assert all(set(VIEW_TAGS) <= set(r.data.tags) for r in shown), "every shown run fills the key columns"
    assert len({r.data.tags["variant"] for r in shown}) > 1, "the grouping has groups to show"

    browse = next(line for line in lines if line.startswith("browse: "))
    assert browse == f"browse: {ui_link(uri, exp_id)}"
    assert f"#/experiments/{exp_id}/runs?workflowType=machine_learning&viewStateShareKey={VIEW_KEY}" in browse
    # the environment's own mlflow, by its absolute path: the command works without activating it
    command, url = browse.removeprefix("browse: ").split(", then ")
    mlflow_exe, *args = shlex.split(command)
    assert args == ["ui", "--backend-store-uri", uri] and url.startswith("http://127.0.0.1:5000/")
    assert os.path.isabs(mlflow_exe) and os.access(mlflow_exe, os.X_OK)
    assert Path(mlflow_exe).parent == Path(sys.executable).parent, "the mlflow of the interpreter that runs the study"
    # a filter or order in the URL (searchFilter, orderByKey, ...) would make the UI ignore the saved view
    query = parse_qs(urlsplit(urlsplit(browse.split(", then ")[1]).fragment).query)
    assert query == {"workflowType": ["machine_learning"], "viewStateShareKey": [VIEW_KEY]}


def test_a_report_names_the_environments_mlflow_as_a_clone_reads_it(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A report page's command: the store and the ``mlflow`` relative to the clone's root when
    inside it (a committed report says the same to every clone), absolute otherwise."""
    clone = tmp_path / "clone"
    exe = clone / ".venv" / "bin" / "mlflow"
    exe.parent.mkdir(parents=True)
    exe.write_text("#!/bin/sh\n")
    exe.chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(exe.parent / "python"))
    monkeypatch.chdir(clone)
    assert browse_command(f"sqlite:///{clone / 'mlflow.db'}") == ".venv/bin/mlflow ui --backend-store-uri sqlite:///mlflow.db"
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    assert browse_command("sqlite:////data/m.db") == f"{exe} ui --backend-store-uri sqlite:////data/m.db"
    assert browse_command("http://tracking:5000") == "open http://tracking:5000"


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
