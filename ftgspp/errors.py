"""User-facing input errors.

Anything wrong with what the user gave us (a file, a key, a value) is raised as
``InputError``. Command-line entry points catch it, print its one-line message and
exit with status 2, without a traceback.
"""

from __future__ import annotations

import sys
from pathlib import Path


class InputError(Exception):
    """Bad user input. ``str(err)`` is one line naming the file or key and the problem."""

    def __init__(self, where: str | Path, problem: str) -> None:
        self.where = str(where)
        self.problem = problem
        super().__init__(f"{self.where}: {problem}")


def exit_on_input_error(err: InputError) -> None:
    """Print the error as one line on stderr and exit with status 2."""
    print(f"error: {err}", file=sys.stderr)
    raise SystemExit(2)
