"""A study logged over HTTP to a real ``mlflow server`` (started here on a free local port)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
from conftest import TOY_STUDIES
from fakes import LOSS_STEPS, fake_generate, fake_train

from harness.report.writer import write_report
from harness.run.runner import run_study
from harness.spec.runs import Selection
from harness.tracking.records import load_runs, open_store

pytestmark = pytest.mark.slow
START_TIMEOUT_S = 120


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def mlflow_server(tmp_path: Path, mlflow_template: Path):
    """``mlflow server`` on 127.0.0.1 with its own SQLite store; killed afterwards."""
    import shutil

    shutil.copyfile(mlflow_template, tmp_path / "server.db")
    port = _free_port()
    mlflow_bin = Path(sys.executable).with_name("mlflow")
    cmd = [str(mlflow_bin), "server", "--host", "127.0.0.1", "--port", str(port), "--workers", "1",
           "--backend-store-uri", f"sqlite:///{tmp_path / 'server.db'}",
           "--artifacts-destination", str(tmp_path / "server_artifacts")]
    log = open(tmp_path / "server.log", "w")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, cwd=tmp_path)
    uri = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            try:
                with urllib.request.urlopen(uri + "/health", timeout=2) as resp:
                    if resp.status == 200:
                        break
            except OSError:
                pass
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"mlflow server did not start: {(tmp_path / 'server.log').read_text()[-2000:]}")
            time.sleep(0.5)
        yield uri
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=20)
        log.close()


def test_parallel_study_logs_over_http(mlflow_server: str, workdir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MLFLOW_TRACKING_URI", mlflow_server)
    out = run_study("toy", Selection(variants=["baseline", "wild"], seeds=2), jobs=2, studies_dir=TOY_STUDIES,
                    train_fn=fake_train, generate=fake_generate, echo=lambda s: None)
    assert (out.launched, out.finished, out.diverged) == (4, 2, 2), out.results
    assert not Path("mlflow.db.lock").exists(), "no SQLite lock when logging over HTTP"
    store = open_store(mlflow_server)
    runs = load_runs(store, "ftgspp/toy", "toy")
    assert sorted((r.tags["variant"], r.status) for r in runs) == [("baseline", "FINISHED")] * 2 + [("wild", "FAILED")] * 2
    for rec in runs:
        assert rec.tags["mlflow.parentRunId"] == out.parent_run_id
        if rec.status == "FINISHED":
            assert len(store.client.get_metric_history(rec.run_id, "loss")) == LOSS_STEPS
            assert rec.artifact_uri.startswith("mlflow-artifacts:")
            assert {a.path for a in store.client.list_artifacts(rec.run_id)} >= {"config.yaml", "diagnostics"}
    index = write_report("toy", None, studies_dir=TOY_STUDIES, echo=lambda s: None)
    assert (index.parent / "diagnostics" / "baseline" / "easy" / "lifetime_hist.png").is_file()
