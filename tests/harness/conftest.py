"""Shared fixtures for the harness tests: a working directory with an empty MLflow store,
the toy study folder, and the fake trainer / scene generator wired in."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
TOY_STUDIES = HERE / "studies"


@pytest.fixture(scope="session")
def mlflow_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An initialised, empty ``mlflow.db`` (creating one runs ~20 migrations: do it once)."""
    from harness.tracking.store import Store

    folder = tmp_path_factory.mktemp("mlflow_template")
    Store(f"sqlite:///{folder / 'mlflow.db'}").client.search_experiments()
    return folder / "mlflow.db"


def prepare_workdir(path: Path, template: Path, mp: pytest.MonkeyPatch) -> Path:
    """chdir into ``path`` with a fresh copy of the empty store; tracking env cleared."""
    path.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(template, path / "mlflow.db")
    mp.chdir(path)
    mp.delenv("MLFLOW_TRACKING_URI", raising=False)
    return path


def use_fakes(mp: pytest.MonkeyPatch) -> None:
    """Route ``study`` commands to the toy studies, the fake trainer and the fake generator."""
    import fakes

    import harness.run.scenes
    import harness.run.training
    import harness.spec.study_files

    mp.setattr(harness.spec.study_files, "STUDIES_DIR", TOY_STUDIES)
    mp.setattr(harness.run.training, "run_training", fakes.fake_train)
    mp.setattr(harness.run.scenes, "_default_generator", lambda: fakes.fake_generate)


@pytest.fixture
def workdir(tmp_path: Path, mlflow_template: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    return prepare_workdir(tmp_path / "work", mlflow_template, monkeypatch)


@pytest.fixture
def fakes_on(monkeypatch: pytest.MonkeyPatch) -> None:
    use_fakes(monkeypatch)
