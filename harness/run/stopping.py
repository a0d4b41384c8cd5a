"""Stop a study the way Ctrl-C does, on SIGTERM and SIGHUP too.

A closed terminal sends SIGHUP, SLURM at a time limit or preemption and most batch systems
SIGTERM, Ctrl-C SIGINT. Inside ``on_signals()`` each of them raises ``Stopped`` in the main
thread - a ``KeyboardInterrupt``, so everything that cleans up after Ctrl-C (a run's task, a
launcher, ``subprocess``) cleans up after it too. Only the first signal counts; later ones are
ignored while the process stops. A signal this process ignores (``nohup`` ignores SIGHUP, a
shell's background job SIGINT) stays ignored.

In the study process the handler first tells its worker processes (``forward``: SIGTERM to each
direct child; a submitit controller passes it on to its job, a run's training child flushes what
it has) and runs the callbacks of ``while_stopping`` (the runner's: stop launching, let the
workers record their runs KILLED), then raises. After the launcher has let ``Stopped`` through,
``reap`` waits for what is left of the workers and kills it after the grace period
(``$FTGSPP_STOP_GRACE_S``, default 10 s). The same handler in a worker (``run.task``) makes its
run's task record the run KILLED and refuse any further task of that process.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from typing import Callable, Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
GRACE_ENV = "FTGSPP_STOP_GRACE_S"
DEFAULT_GRACE_S = 10.0

_received: list[int] = []  # the signal that stopped this process, once one has
_installed: list[bool] = []
_callbacks: list[Callable[[], None]] = []


class Stopped(KeyboardInterrupt):
    """The process was stopped by signal ``signum``; ``finished`` and ``killed`` are the
    invocation's counts, filled in by the runner that recorded them."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.finished = 0
        self.killed = 0

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_status(self) -> int:
        """128 + the signal's number, as a shell reports a process the signal ended (130, 143, 129)."""
        return 128 + self.signum


def as_stopped(exc: BaseException) -> Stopped:
    """``exc`` as a ``Stopped``: a plain ``KeyboardInterrupt`` (Ctrl-C before the handlers were on) is SIGINT."""
    return exc if isinstance(exc, Stopped) else Stopped(signal.SIGINT)


def killed_tags(exc: BaseException) -> dict[str, str]:
    """The tags of a run ended KILLED by ``exc``: ``failure=interrupted``, ``stop_signal``, ``error``."""
    if isinstance(exc, KeyboardInterrupt):
        name = as_stopped(exc).name
        return {"failure": "interrupted", "stop_signal": name, "error": f"stopped by {name}"}
    return {"failure": "interrupted", "error": f"interrupted ({type(exc).__name__})"}


def received() -> int | None:
    """The signal that is stopping this process, if one is."""
    return _received[0] if _received else None


def reset() -> None:
    """Forget an earlier stop (a new invocation in the same process, e.g. a test's)."""
    _received.clear()


def grace_seconds() -> float:
    """How long a stopping process waits for its workers (and a run for its training child)."""
    return float(os.environ.get(GRACE_ENV, DEFAULT_GRACE_S))


@contextlib.contextmanager
def on_signals() -> Iterator[None]:
    """Within: SIGINT, SIGTERM and SIGHUP raise ``Stopped`` (see the module doc). Nested uses and
    threads other than the main one leave the handlers as they are."""
    if _installed or threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in SIGNALS}
    for s in SIGNALS:
        if previous[s] is not signal.SIG_IGN:
            signal.signal(s, _handler)
    _installed.append(True)
    try:
        yield
    finally:
        _installed.clear()
        for s, handler in previous.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)


@contextlib.contextmanager
def while_stopping(callback: Callable[[], None]) -> Iterator[None]:
    """Run ``callback`` in the signal handler, before ``Stopped`` is raised, while inside."""
    _callbacks.append(callback)
    try:
        yield
    finally:
        _callbacks.remove(callback)


def _handler(signum: int, frame: object) -> None:
    if _received:
        return  # stopping already
    _received.append(signum)
    forward()
    for callback in list(_callbacks):
        try:
            callback()
        except Exception:  # a callback is best effort: reap and the runner's sweep come after it
            pass
    raise Stopped(signum)


def _children(recursive: bool = False) -> list:
    import psutil

    try:
        return psutil.Process().children(recursive=recursive)
    except psutil.Error:
        return []


def forward() -> None:
    """SIGTERM to each direct child process: a worker records its run KILLED, a submitit
    controller passes it on to its job, a training child flushes its curve. SIGTERM whatever this
    process got: a submitit controller kills its job within a second of a SIGINT."""
    import psutil

    for child in _children():
        with contextlib.suppress(psutil.Error):
            child.send_signal(signal.SIGTERM)


def reap(grace_s: float | None = None) -> int:
    """Wait until every descendant process has ended, telling new direct children to stop too,
    and kill what is left after ``grace_s``; returns how many had to be killed."""
    import psutil

    deadline = time.monotonic() + (grace_seconds() if grace_s is None else grace_s)
    told: set[int] = set()
    while time.monotonic() < deadline:
        alive = [p for p in _children(recursive=True) if _running(p)]
        if not alive:
            return 0
        for child in _children():
            if child.pid not in told:
                told.add(child.pid)
                with contextlib.suppress(psutil.Error):
                    child.send_signal(signal.SIGTERM)
        time.sleep(0.1)
    left = [p for p in _children(recursive=True) if _running(p)]
    for p in left:
        with contextlib.suppress(psutil.Error):
            p.kill()
    psutil.wait_procs(left, timeout=5)
    return len(left)


def _running(p: object) -> bool:
    """A live process that holds work: not a zombie, not multiprocessing's (loky's) resource
    tracker, which ignores SIGTERM and ends by itself with this process."""
    import psutil

    try:
        return p.status() != psutil.STATUS_ZOMBIE and not any(  # type: ignore[attr-defined]
            "resource_tracker" in part for part in p.cmdline())  # type: ignore[attr-defined]
    except psutil.Error:
        return False
