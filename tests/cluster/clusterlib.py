"""Helpers and fixtures of the cluster tests (``make test-cluster``).

The tests - a real PostgreSQL-backed ``mlflow server``, a real one-node SLURM, headless
Chromium - need root-only services that ``install.sh`` installs. Their files are named
``cluster_*.py`` so the default ``make test`` does not collect them; ``make test-cluster``
names them explicitly. A missing prerequisite fails with a message, never skips.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
HARNESS_TESTS = REPO / "tests" / "harness"
sys.path.insert(0, str(HARNESS_TESTS))  # fakes, drive_study

def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def require(ok: bool, what: str) -> None:
    """Fail (not skip) with a message naming the missing prerequisite."""
    if not ok:
        pytest.fail(f"prerequisite missing: {what} (run `make test-cluster`, which installs it as root)",
                    pytrace=False)


def wait_http(url: str, proc: subprocess.Popen, log: Path, timeout_s: float = 180) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(url, timeout=2) as resp:
                if resp.status == 200:
                    return
        except OSError:
            pass
        if proc.poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"{url} did not come up: {log.read_text()[-3000:]}", pytrace=False)
        time.sleep(0.5)


def public_tmpdir(prefix: str) -> Path:
    """A folder other users (postgres, slurm) can reach: pytest's tmp_path is private to root."""
    path = Path(tempfile.mkdtemp(prefix=prefix, dir="/var/tmp"))
    path.chmod(0o755)
    return path


@pytest.fixture(scope="module")
def pg_server():
    """``ftgspp-server`` (PostgreSQL + mlflow server) in a fresh folder; stopped afterwards."""
    from harness.cli.server import pg_bindir

    try:
        pg_bindir()
    except Exception as exc:
        require(False, f"PostgreSQL ({exc})")
    root = public_tmpdir("ftgspp-pg-")
    port, pg_port = free_port(), free_port()
    log = root / "server.log"
    exe = Path(sys.executable).with_name("ftgspp-server")
    cmd = [str(exe), "--root", str(root / "srv"), "--port", str(port), "--pg-port", str(pg_port), "--workers", "2"]
    with open(log, "w") as fh:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, start_new_session=True)
    uri = f"http://127.0.0.1:{port}"
    try:
        wait_http(uri + "/health", proc, log)
        yield {"uri": uri, "root": root, "pg_port": pg_port, "log": log}
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture(scope="module")
def slurm_cluster():
    """A one-node SLURM (``slurm_one_node.sh``) in a fresh folder; ``SLURM_CONF`` for clients."""
    require(os.geteuid() == 0, "root (slurm_one_node.sh starts munged, slurmctld and slurmd)")
    require(shutil.which("slurmctld") is not None or Path("/usr/sbin/slurmctld").exists(), "slurm-wlm (Debian)")
    root = public_tmpdir("ftgspp-slurm-")
    script = HERE / "slurm_one_node.sh"
    started = subprocess.run(["bash", str(script), "start", str(root)], capture_output=True, text=True, timeout=180)
    require(started.returncode == 0, f"a one-node SLURM: {started.stdout[-1000:]} {started.stderr[-2000:]}")
    try:
        yield {"conf": str(root / "slurm.conf"), "root": root}
    finally:
        subprocess.run(["bash", str(script), "stop", str(root)], timeout=60)
        shutil.rmtree(root, ignore_errors=True)
