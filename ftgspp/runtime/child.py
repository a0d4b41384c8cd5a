"""One training run in a child process when this process's environment is not the run's.

Kernel dispatch is fixed when the libraries load, so a run whose determinism settings
differ from this process's trains in a child process started with the right environment,
and the parent collects its metrics, params, loss curve, artifacts and determinism domain:

- ``determinism=portable`` from a process without the portable environment (``ftgspp train
  determinism=portable``, a ``study run`` mixing modes, or ``train()`` called from Python);
- ``determinism=default`` from a process that has it;
- ``dispatch=avx512|avx2|baseline``: the same config, seed and initialisation trained as
  if on another CPU (torch's kernel set, ``ATEN_CPU_CAPABILITY``), which measures the
  hardware share of run-to-run variance (secret 5). ``native`` is this machine's best.

The child's output (progress bar, log lines, errors) is copied to the parent's stderr as it
comes and to ``OUT_DIR/dispatch_child.log``; a failed child's last line is in the parent's error,
and an ``InputError`` in the child is raised again in the parent.

Stopping: SIGTERM, SIGHUP or SIGINT end the child: it writes the loss curve it has so far
(``{"stopped": "SIGTERM", "curve": ...}``) and exits with 128 + the signal. A parent interrupted
while its child trains (its own Ctrl-C or stop signal) sends the child SIGTERM, waits up to
``$FTGSPP_STOP_GRACE_S`` (default 10 s) for it, logs the curve it left to the tracker and lets the
interruption go on. A child stopped by itself (killed by someone else) fails the run with the
signal named.

    python -m ftgspp.trainer OUT_DIR/dispatch_config.json   # what the parent starts (child_main)

(The entry point is the trainer's ``__main__``: this module cannot import the trainer, which
imports it.)
"""

from __future__ import annotations

import codecs
import json
import logging
import os
import re
import signal
import subprocess
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Callable

from ftgspp.config import TrainConfig, train_config_from_dict
from ftgspp.errors import InputError
from ftgspp.runtime.determinism import MARKER, PORTABLE_FIXED, portable_environment
from ftgspp.tracker import RunResult, Tracker

DISPATCHES = {"native": None, "avx512": "avx512", "avx2": "avx2", "baseline": "default"}
CHILD = "FTGSPP_RUN_CHILD"  # set in a child, so a mismatch there is an error, not another child
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
GRACE_ENV = "FTGSPP_STOP_GRACE_S"  # the study harness's stop grace too (harness.run.stopping)
DEFAULT_GRACE_S = 10.0


def needs_child(cfg: TrainConfig) -> bool:
    """Whether this process's environment differs from what ``cfg`` needs (see the module doc);
    ``InputError`` for a dispatch no process can have (``check_dispatch``)."""
    check_dispatch(cfg)
    portable_here = os.environ.get(MARKER) == "portable"
    if cfg.determinism == "portable":
        return not portable_here
    if portable_here:
        return True
    want = DISPATCHES[cfg.dispatch]
    return want is not None and os.environ.get("ATEN_CPU_CAPABILITY") != want


def child_environment(cfg: TrainConfig) -> dict[str, str]:
    """This process's environment turned into the one ``cfg`` needs."""
    env = dict(os.environ)
    if cfg.determinism == "portable":
        env = portable_environment(env)
    else:  # back to this machine's own dispatch, then the requested kernel set
        for key in (*PORTABLE_FIXED, "NPY_DISABLE_CPU_FEATURES", "OPENCV_CPU_DISABLE", MARKER):
            env.pop(key, None)
        if DISPATCHES[cfg.dispatch] is not None:
            env["ATEN_CPU_CAPABILITY"] = DISPATCHES[cfg.dispatch]
    env[CHILD] = "1"
    return env


def check_dispatch(cfg: TrainConfig) -> None:
    """One-line ``InputError`` for an unknown dispatch or one combined with portable mode."""
    if cfg.dispatch not in DISPATCHES:
        raise InputError("dispatch", f"unknown value '{cfg.dispatch}' (choose from {', '.join(DISPATCHES)})")
    if cfg.dispatch != "native" and cfg.determinism == "portable":
        raise InputError("dispatch", "portable mode pins the kernel dispatch; use dispatch=native with it")


def train_in_child(cfg: TrainConfig, tracker: Tracker) -> RunResult:
    """Train ``cfg`` in a child process with the environment it needs; log what it wrote to ``tracker``."""
    out_dir = Path(cfg.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    config_file = out_dir / "dispatch_config.json"
    config_file.write_text(json.dumps({"config": asdict(cfg)}, indent=2))
    if os.environ.get(CHILD):
        raise RuntimeError("a training child process did not get the environment its run needs")
    result_file = out_dir / "dispatch_result.json"
    result_file.unlink(missing_ok=True)  # an earlier child's, in a resumed run's folder
    try:
        code, last = _run_streamed([sys.executable, "-m", "ftgspp.trainer", str(config_file)],
                                   child_environment(cfg), out_dir / "dispatch_child.log")
    except BaseException:  # this process is being stopped: the child has been too; keep what it left
        _log_curve(_read_result(result_file), tracker)
        raise
    blob = _read_result(result_file)
    if "input_error" in blob:  # the child's one-line error is this process's
        raise InputError(**blob["input_error"])
    if "stopped" in blob:  # stopped by a signal of its own, not through this process
        _log_curve(blob, tracker)
        raise RuntimeError(f"training (determinism={cfg.determinism}, dispatch={cfg.dispatch}) was stopped in its "
                           f"child process by {blob['stopped']}")
    if code != 0 or not blob:
        raise RuntimeError(f"training (determinism={cfg.determinism}, dispatch={cfg.dispatch}) failed in its "
                           f"child process: {last}")
    _log_curve(blob, tracker)
    tracker.set_tags({f"determinism.{k}": v for k, v in blob["domain"].items()})
    tracker.log_params(blob.get("params", {}))
    tracker.log_metrics({k: v for k, v in blob["metrics"].items() if v is not None})
    for path, artifact_path in blob["artifacts"]:
        tracker.log_artifact(Path(path), artifact_path)
    return RunResult(status=blob["status"], metrics=blob["metrics"], failure=blob["failure"], out_dir=out_dir,
                     artifacts=[Path(p) for p, where in blob["artifacts"] if where == "renders"])


def _read_result(result_file: Path) -> dict:
    """What the child wrote for the parent ({} when nothing, or nothing whole)."""
    try:
        return json.loads(result_file.read_text())
    except (OSError, ValueError):
        return {}


def _log_curve(blob: dict, tracker: Tracker) -> None:
    """Log the child's per-step curve (as much of it as ``blob`` has) to ``tracker``."""
    for step, values in blob.get("curve", []):
        tracker.log_metrics(values, step=step)


def _run_streamed(argv: list[str], env: dict[str, str], log_file: Path) -> tuple[int, str]:
    """Run ``argv`` with its stdout and stderr (merged) copied to this process's stderr as they
    come and to ``log_file``; returns its exit code and its last non-empty line. Interrupted
    (Ctrl-C, a stop signal), it stops the child first (``_stop_child``) and lets the interruption go on."""
    decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
    tail = ""
    with open(log_file, "wb") as log, subprocess.Popen(argv, env=env, stdout=subprocess.PIPE,
                                                       stderr=subprocess.STDOUT) as proc:
        assert proc.stdout is not None
        try:
            while chunk := proc.stdout.read1(1 << 16):  # whatever is there: a progress bar's \r updates too
                log.write(chunk)
                log.flush()  # a reader of the log (tail -f) sees it as it comes
                text = decoder.decode(chunk)
                sys.stderr.write(text)
                sys.stderr.flush()
                tail = (tail + text)[-4096:]
            code = proc.wait()
        except BaseException:
            _stop_child(proc, log)
            raise
    lines = [line for line in re.split(r"[\r\n]", tail) if line.strip()]
    return code, lines[-1] if lines else "no output"


def _stop_child(proc: subprocess.Popen, log: object) -> None:
    """SIGTERM to the training child, then wait for it to write what it has and exit (its last
    output goes to the log), up to the grace period; killed after that."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
    try:
        out, _ = proc.communicate(timeout=float(os.environ.get(GRACE_ENV, DEFAULT_GRACE_S)))
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    except BaseException:  # a second interruption: no more waiting
        proc.kill()
        raise
    if out:
        log.write(out)  # type: ignore[attr-defined]


class _Recorder:
    """The child's tracker: keeps the per-step curve, the params the trainer logs (the initial
    count, which render stage ran, ...) and the artifacts for the parent."""

    def __init__(self) -> None:
        self.curve: list[tuple[int | None, dict]] = []
        self.params: dict[str, str] = {}
        self.artifacts: list[tuple[str, str | None]] = []

    def log_params(self, params):
        self.params.update({k: str(v) for k, v in params.items()})

    def log_metrics(self, metrics, step=None):
        if step is not None:
            self.curve.append((step, dict(metrics)))

    def log_artifact(self, path, artifact_path=None):
        self.artifacts.append((str(path), artifact_path))

    def set_tags(self, tags):
        pass


def _stop_on_signals(result_file: Path, recorder: _Recorder) -> None:
    """SIGTERM, SIGHUP and SIGINT end the child at once, after it wrote the curve it has for the
    parent (``{"stopped": "SIGTERM", "curve": ...}``): exiting from the handler, not raising into
    the training, whose Numba kernels and autograd turn an exception raised inside them into
    another one. Checkpoints are written atomically, so none is left half-written. A signal the
    child inherited as ignored stays ignored."""

    def handler(signum: int, frame: object) -> None:
        try:
            result_file.write_text(json.dumps({"stopped": signal.Signals(signum).name, "curve": recorder.curve}))
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(128 + signum)

    for s in STOP_SIGNALS:
        if signal.getsignal(s) is not signal.SIG_IGN:
            signal.signal(s, handler)


def child_main(config_file: Path, train: Callable[..., RunResult]) -> int:
    """The child: train the saved config with ``train`` and write what the parent collects (the
    curve so far when a signal stops it)."""
    from ftgspp.data.load import load_scene

    handler = logging.StreamHandler()  # the parent shows what the child logs
    handler.setFormatter(logging.Formatter("[%(asctime)s][%(name)s][%(levelname)s] - %(message)s"))
    package_log = logging.getLogger("ftgspp")
    package_log.addHandler(handler)
    package_log.setLevel(logging.INFO)
    blob = json.loads(config_file.read_text())
    cfg = train_config_from_dict(blob["config"])
    result_file = Path(cfg.out_dir) / "dispatch_result.json"
    recorder = _Recorder()
    _stop_on_signals(result_file, recorder)
    try:
        result = train(cfg, load_scene(cfg.data), recorder)
    except InputError as err:  # raised again in the parent, as one line
        result_file.write_text(json.dumps({"input_error": {"where": err.where, "problem": err.problem}}))
        return 2
    domain = json.loads((Path(cfg.out_dir) / "determinism.json").read_text())
    result_file.write_text(json.dumps({
        "status": result.status, "failure": result.failure, "metrics": result.metrics, "curve": recorder.curve,
        "domain": domain, "params": recorder.params, "artifacts": recorder.artifacts}))
    return 0

