"""Several ``study run`` invocations sharing one ``mlflow server`` on a real PostgreSQL.

1. Two concurrent invocations of the secret5 smoke study (real trainer, both generating the
   synthetic scene at once): every (variant, scene, seed) FINISHED exactly once, none FAILED.
2. An invocation killed with SIGKILL mid-run leaves a RUNNING run whose lease nobody may
   touch while it is fresh; once it expires, another invocation takes it over (marks it
   FAILED, ``lease expired``) and finishes it.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

from clusterlib import HARNESS_TESTS, pg_server  # noqa: F401  (fixture)

from harness.run.lease import is_live
from harness.tracking.records import load_runs, open_store

STUDY_BIN = Path(sys.executable).with_name("study")


def _runs(uri: str, study: str, kind: str = "run"):
    return load_runs(open_store(uri), f"ftgspp/{study}", study, kind=kind)


def test_two_concurrent_smoke_invocations_finish_each_run_once(pg_server, tmp_path: Path) -> None:
    uri = pg_server["uri"]
    env = {**os.environ, "MLFLOW_TRACKING_URI": uri}
    cmd = [str(STUDY_BIN), "run", "secret5", "--profile", "smoke", "--seeds", "3", "--variants", "baseline,cc"]
    procs = [subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for _ in range(2)]
    outs = [p.communicate(timeout=1200)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], [o[-3000:] for o in outs]
    runs = _runs(uri, "secret5")
    finished = Counter(r.key for r in runs if r.status == "FINISHED")
    assert len(finished) == 6 and set(finished.values()) == {1}, "every run FINISHED exactly once"
    assert [r.status for r in runs] == ["FINISHED"] * 6, "no live run marked FAILED, nothing trained twice"
    owners = Counter(r.tags["lease.owner"].rsplit(":", 1)[1] for r in runs)
    print(f"runs per invocation: {dict(owners)}")
    assert set(owners) <= {str(p.pid) for p in procs}
    for rec in runs:
        assert rec.artifact_uri.startswith("mlflow-artifacts:"), "artifacts proxied through the server"


def test_killed_invocations_run_is_taken_over_after_its_lease(pg_server, tmp_path: Path) -> None:
    uri = pg_server["uri"]
    env = {**os.environ, "MLFLOW_TRACKING_URI": uri, "FAKE_TRAIN_SLEEP": "4", "PYTHONPATH": str(HARNESS_TESTS)}
    cmd = [sys.executable, str(HARNESS_TESTS / "drive_study.py"), "run", "toy", "--variants", "baseline",
           "--seeds", "3", "--lease", "6"]
    victim = subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while not any(r.status == "RUNNING" for r in _runs(uri, "toy")):
            assert victim.poll() is None and time.monotonic() < deadline, "victim never started a run"
            time.sleep(0.2)
        os.kill(victim.pid, signal.SIGKILL)
    finally:
        victim.wait(timeout=60)
    (orphan,) = [r for r in _runs(uri, "toy") if r.status == "RUNNING"]
    assert orphan.tags["lease.owner"].endswith(f":{victim.pid}")

    # a second invocation right away: it must not fail the orphan while its lease is fresh
    second = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert second.returncode == 0, second.stdout[-3000:] + second.stderr[-3000:]
    # then a third, after the orphan's lease has run out, if the second left it
    while any(is_live(r) for r in _runs(uri, "toy")):
        time.sleep(0.5)
    third = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert third.returncode == 0, third.stdout[-3000:] + third.stderr[-3000:]

    runs = {r.run_id: r for r in _runs(uri, "toy")}
    killed = runs[orphan.run_id]
    assert killed.status == "FAILED" and killed.failure == "interrupted" and "lease expired" in killed.error
    (taker,) = [r for r in runs.values() if r.tags.get("lease.took_over") == orphan.run_id]
    assert taker.status == "FINISHED" and taker.key == orphan.key
    finished = Counter(r.key for r in runs.values() if r.status == "FINISHED")
    assert len(finished) == 3 and set(finished.values()) == {1}, "every run FINISHED exactly once"
    print(f"orphan {orphan.run_id[:8]} ({killed.error}) taken over by {taker.run_id[:8]}"
          f" from {taker.tags['lease.owner']}")
