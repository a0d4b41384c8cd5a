"""A study run's log file: what a run prints goes there; its warnings also reach the terminal.

The terminal of ``study run`` shows the plan, a line per run as it starts and as it finishes, and
warnings; everything else a run says is in its log file, ``<run's output folder>/<job name>.log``
(``study_secret5.log``). Two routes fill it:

- log records of the job's own process (the trainer's ``ftgspp.*`` loggers: the initialiser's
  ``frame 0: 9 views, 10 pairs, ...``): Hydra's job logging, ``conf/hydra/job_logging/study.yaml``
  (records to the file; WARNING and above also to the terminal as ``[run] LABEL: WARNING: ...``);
- text written to stdout and stderr while the run trains (``capture``): the output of a training
  child process (``ftgspp.runtime.child`` copies it to stderr: its log lines, its progress bar),
  Python warnings (NumPy's RuntimeWarnings), a progress bar. All of it goes to the file; a log
  record of level WARNING or above among it also to the terminal, in the same one-line form.

Hydra's launcher lines (``Launching jobs``, ``#0 : overrides ...``) go to ``launcher.log`` in the
study's sweep folder (``conf/hydra/hydra_logging/study.yaml``); a run's log starts with its own.
"""

from __future__ import annotations

import io
import re
import sys
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from pathlib import Path
from typing import Iterator, TextIO

# a log record as ftgspp's and Hydra's formatter writes it: [time][logger][LEVEL] - message
RECORD = re.compile(r"\]\[(?P<name>[\w.]+)\]\[(?P<level>WARNING|ERROR|CRITICAL)\] - (?P<message>.*)$")
KEEP = 4096  # characters of an unfinished line kept to look at (a progress bar's updates have no newline)


def terminal_line(label: str, level: str, message: str) -> str:
    """How a run's warning reads on the terminal (as ``conf/hydra/job_logging/study.yaml`` writes it)."""
    return f"[run] {label}: {level}: {message}"


class _Tee(io.TextIOBase):
    """A text stream that writes to the run's log file and passes warning records on."""

    def __init__(self, log: TextIO, terminal: TextIO, label: str) -> None:
        self._log, self._terminal, self._label = log, terminal, label
        self._partial = ""

    @property
    def encoding(self) -> str:  # type: ignore[override]
        return "utf-8"

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        self._log.write(text)
        *lines, rest = (self._partial + text).split("\n")
        self._partial = rest[-KEEP:]
        for line in lines:
            self._pass_on(line)
        return len(text)

    def _pass_on(self, line: str) -> None:
        found = RECORD.search(line.rsplit("\r", 1)[-1].rstrip())
        if found:
            self._terminal.write(terminal_line(self._label, found["level"], found["message"]) + "\n")
            self._terminal.flush()

    def flush(self) -> None:
        self._log.flush()

    def finish(self) -> None:
        """Look at the last, unfinished line too."""
        self._pass_on(self._partial)
        self._partial = ""


@contextmanager
def capture(path: Path, label: str, header: str = "") -> Iterator[None]:
    """Inside the block, stdout and stderr of this process go to the log file ``path``
    (appended), and the WARNING/ERROR records among them also to the terminal (this process's
    stdout when the block starts), as one line naming the run ``label``. ``header``: a first line
    for the file."""
    terminal = sys.stdout
    with open(path, "a", encoding="utf-8", buffering=1) as log:
        if header:
            log.write(header + "\n")
        tee = _Tee(log, terminal, label)
        try:
            with redirect_stdout(tee), redirect_stderr(tee):
                yield
        finally:
            tee.finish()
