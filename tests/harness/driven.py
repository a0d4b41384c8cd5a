"""Helpers for the tests that drive real ``study run`` processes (test_signals.py, test_exit_status.py):
start one with the gated fake trainer (``gated.py``), wait for a state of the run or of its output,
read the tracking store back. Waits poll a condition; their timeouts are safety nets only.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

from conftest import HERE

from harness.tracking.records import RunRecord, load_runs, open_store

SAFETY_S = 240.0  # no condition here should take more than seconds; this only ends a hung test


def env(gate: Path, gated_seeds: str | None = None, **extra: str) -> dict[str, str]:
    """The environment of a driven ``study``: the fakes importable, the gate, a short stop grace."""
    out = {**os.environ, "PYTHONPATH": str(HERE), "GATE_FILE": str(gate), "FTGSPP_STOP_GRACE_S": "10", **extra}
    out.pop("GATE_SEEDS", None)
    if gated_seeds is not None:
        out["GATE_SEEDS"] = gated_seeds
    return out


class Driven:
    """One ``study`` process (``gated.py`` by default) with its stdout and stderr in files."""

    def __init__(self, name: str, args: list[str], environ: dict[str, str], module: str | None = None) -> None:
        self.out, self.err = Path(f"{name}.out"), Path(f"{name}.err")
        argv = [sys.executable, "-m", module] if module else [sys.executable, str(HERE / "gated.py")]
        with open(self.out, "w") as out, open(self.err, "w") as err:
            self.proc = subprocess.Popen([*argv, *args], env=environ, stdout=out, stderr=err,
                                         preexec_fn=_default_stop_signals)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def stdout(self) -> str:
        return self.out.read_text()

    def stderr(self) -> str:
        return self.err.read_text()

    def wait(self) -> int:
        return self.proc.wait(timeout=SAFETY_S)

    def until(self, condition: Callable[[], bool], what: str) -> None:
        """Poll ``condition`` until it holds; fail if the process ends first (or the safety net)."""
        deadline = time.monotonic() + SAFETY_S
        while not condition():
            assert self.proc.poll() is None, \
                f"ended ({self.proc.returncode}) before {what}:\n{self.stdout()}{self.stderr()}"
            assert time.monotonic() < deadline, f"no {what} after {SAFETY_S:.0f} s"
            time.sleep(0.1)


def at_gate(study: str = "toy") -> int:
    """How many runs wait at the gate now (``gated.py`` writes ``at_gate`` into their folders)."""
    return len(list(Path("outputs/studies").glob(f"{study}/*/*/*/seed*/at_gate")))


def uri() -> str:
    return f"sqlite:///{Path('mlflow.db').resolve()}"


def runs(study: str = "toy", kind: str = "run") -> list[RunRecord]:
    return load_runs(open_store(uri()), f"ftgspp/{study}", study, kind=kind)


def loss_steps(run_id: str) -> int:
    return len(open_store(uri()).client.get_metric_history(run_id, "loss"))


def processes_in(folder: Path) -> list[str]:
    """Processes other than this one working in ``folder`` (a study's workers, its training children)."""
    import psutil

    left = []
    for p in psutil.process_iter(["pid", "cwd", "cmdline"]):
        if p.info["pid"] != os.getpid() and p.info["cwd"] == str(folder.resolve()):
            left.append(" ".join(p.info["cmdline"] or []))
    return left


def no_processes_left(folder: Path) -> list[str]:
    """``processes_in(folder)`` once it is empty, or what is still there at the safety net."""
    deadline = time.monotonic() + 30
    while (left := processes_in(folder)) and time.monotonic() < deadline:
        time.sleep(0.1)
    return left


def _default_stop_signals() -> None:
    """The child starts with SIGINT, SIGTERM and SIGHUP at their defaults, as from a terminal: a
    suite started with ``nohup`` or in the background (``make test &``) passes SIG_IGN for SIGHUP
    and SIGINT to every descendant, and a process that inherits an ignored signal keeps ignoring it
    (``harness/run/stopping.on_signals``, as a shell user who ran ``nohup study run`` expects)."""
    import signal

    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, signal.SIG_DFL)
