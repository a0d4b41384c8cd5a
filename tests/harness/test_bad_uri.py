"""A malformed tracking URI is one line and exit status 2 for ``study run``, ``status`` and ``report``
- given as ``tracking.uri=`` or in ``MLFLOW_TRACKING_URI`` - before anything is read or written;
never SQLAlchemy's or MLflow's traceback, never a store or folder made from it."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import HERE

from harness.cli.study import main

BAD = {  # the URI -> words its one line has
    "sqlite_one_slash": ("sqlite:/path/mlflow.db", "is not a SQLite URI"),
    "sqlite_two_slashes": ("sqlite://relative.db", "is not a SQLite URI"),
    "sqlite_no_file": ("sqlite:///", "names no database file"),
    "sqlite_folder": ("sqlite:///afolder", "names the folder"),
    "postgres_one_slash": ("postgresql:/x", "is not a database URL"),
    "postgres_bad_port": ("postgresql+psycopg://me:secret@db:port/mlflow", "is not a database URL"),
    "postgres_nothing": ("postgresql://", "names no host or database"),
    "http_no_colon": ("http//host:5000", "has no scheme"),
    "http_no_host": ("http://", "names no host"),
    "http_bad_port": ("http://host:port", "bad port"),
    "empty": ("", "is empty"),
    "blank": ("   ", "is empty"),
    "folder_path": ("afolder", "has no scheme"),
    "absolute_path": ("/tmp/mlruns", "has no scheme"),
    "unknown_scheme": ("ftp://host/mlflow", "has the scheme 'ftp'"),
    "file_scheme": ("file:///tmp/mlruns", "has the scheme 'file'"),
    "bare_word": ("databricks", "has no scheme"),
}
COMMANDS = (["run", "toy"], ["status", "toy"], ["report", "toy"])


def _one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    captured = capsys.readouterr()
    lines = [line for line in captured.err.splitlines() if line.strip()]
    assert len(lines) == 1 and captured.out == "", captured
    return lines[0]


def _nothing_written(workdir: Path, before: set[str]) -> None:
    assert {p.name for p in workdir.iterdir()} == before, "no store, outputs or scenes made"


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: c[0])
@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_tracking_uri_is_one_line_and_exit_2(case: str, command: list[str], workdir: Path, fakes_on: None,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    uri, words = BAD[case]
    (workdir / "afolder").mkdir()
    before = {p.name for p in workdir.iterdir()}
    with pytest.raises(SystemExit) as exc:
        main([*command, f"tracking.uri={uri}"])
    assert exc.value.code == 2
    line = _one_error_line(capsys)
    assert line.startswith("error: tracking.uri: ") and words in line, line
    assert "secret" not in line, "a password never shows"
    _nothing_written(workdir, before)


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: c[0])
@pytest.mark.parametrize("uri", ["sqlite:/x.db", "http//host", "gopher://x"])
def test_a_bad_uri_in_the_environment_names_the_variable(uri: str, command: list[str], workdir: Path, fakes_on: None,
                                                         monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    before = {p.name for p in workdir.iterdir()}
    with pytest.raises(SystemExit) as exc:
        main(command)
    assert exc.value.code == 2
    assert _one_error_line(capsys).startswith("error: MLFLOW_TRACKING_URI: ")
    _nothing_written(workdir, before)


@pytest.mark.parametrize("command", COMMANDS[1:], ids=lambda c: c[0])
def test_status_and_report_of_an_unreachable_server_are_one_line_at_once(command: list[str], workdir: Path,
                                                                         fakes_on: None,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """Reading from a server that does not answer: one line, not MLflow's minutes of retries."""
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(SystemExit) as exc:
        main([*command, f"tracking.uri=http://127.0.0.1:{port}"])
    assert exc.value.code == 2
    assert "cannot reach an MLflow server" in _one_error_line(capsys)


@pytest.mark.parametrize("command", COMMANDS, ids=lambda c: c[0])
def test_a_bad_uri_in_a_real_process_is_one_line_on_stderr(command: list[str], workdir: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(HERE), "MLFLOW_TRACKING_URI": "sqlite:/tmp/mlflow.db"}
    proc = subprocess.run([sys.executable, str(HERE / "drive_study.py"), *command], env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stdout == "" and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.startswith("error: MLFLOW_TRACKING_URI: 'sqlite:/tmp/mlflow.db' is not a SQLite URI")
