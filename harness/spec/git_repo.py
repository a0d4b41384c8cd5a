"""Read-only, cached access to the git repository a checkout lives in (``spec.registration``).

``repository(folder)`` is the ``Repo`` holding ``folder`` (one per process; None outside a
repository or before its first commit): file versions through one ``git cat-file --batch``
process (``show``), the commits that changed some paths (``log``) and ancestry
(``is_ancestor``), each answer cached. ``forget()`` drops them (``registration.forget``).
"""

from __future__ import annotations

import atexit
import subprocess
from pathlib import Path


class Repo:
    """Read-only access to one git repository; every answer cached for the life of the object."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self._batch: subprocess.Popen | None = None
        self._blobs: dict[str, bytes | None] = {}
        self._logs: dict[tuple[str, tuple[str, ...]], list[tuple[str, str]]] = {}
        self._ancestor: dict[tuple[str, str], bool | None] = {}
        self.head = self._git("rev-parse", "HEAD")
        self.shallow = self._git("rev-parse", "--is-shallow-repository") == "true"

    def _git(self, *args: str) -> str:
        out = subprocess.run(["git", "-C", str(self.root), *args], capture_output=True, text=True, timeout=60)
        return out.stdout.strip() if out.returncode == 0 else ""

    def show(self, commit: str, path: str) -> bytes | None:
        """The file ``path`` (relative to the root) at ``commit``; None when it is absent there."""
        key = f"{commit}:{path}"
        if key not in self._blobs:
            if self._batch is None:
                self._batch = subprocess.Popen(["git", "-C", str(self.root), "cat-file", "--batch"],
                                               stdin=subprocess.PIPE, stdout=subprocess.PIPE)
            assert self._batch.stdin is not None and self._batch.stdout is not None
            self._batch.stdin.write(key.encode() + b"\n")
            self._batch.stdin.flush()
            header = self._batch.stdout.readline().split()
            if len(header) == 3 and header[1] == b"blob":
                body = self._batch.stdout.read(int(header[2]))
                self._batch.stdout.read(1)  # the newline after each object
                self._blobs[key] = body
            else:  # "<key> missing", or a tree: no such file there
                if len(header) == 3:
                    self._batch.stdout.read(int(header[2]) + 1)
                self._blobs[key] = None
        return self._blobs[key]

    def log(self, paths: tuple[str, ...]) -> list[tuple[str, str]]:
        """(commit, first parent or "") of every commit of ``HEAD``'s history that changed ``paths``, newest first."""
        key = (self.head, paths)
        if key not in self._logs:
            text = self._git("log", "--format=%H %P", "HEAD", "--", *paths)
            rows = [line.split() for line in text.splitlines() if line.strip()]
            self._logs[key] = [(r[0], r[1] if len(r) > 1 else "") for r in rows]
        return self._logs[key]

    def is_ancestor(self, older: str, newer: str) -> bool | None:
        """``older`` is ``newer`` or one of its ancestors; None when git cannot tell (a commit this clone lacks)."""
        key = (older, newer)
        if key not in self._ancestor:
            code = subprocess.run(["git", "-C", str(self.root), "merge-base", "--is-ancestor", older, newer],
                                  capture_output=True, timeout=60).returncode
            self._ancestor[key] = True if code == 0 else False if code == 1 else None
        return self._ancestor[key]

    def close(self) -> None:
        if self._batch is not None:
            self._batch.communicate()
            self._batch = None


_REPOS: dict[Path, Repo | None] = {}


def repository(folder: Path) -> Repo | None:
    """The repository holding ``folder`` (one per process), None outside one or without git."""
    folder = Path(folder).resolve()
    if folder not in _REPOS:
        try:
            out = subprocess.run(["git", "-C", str(folder), "rev-parse", "--show-toplevel"], capture_output=True,
                                 text=True, timeout=60)
            top = out.stdout.strip() if out.returncode == 0 else ""
        except (OSError, subprocess.SubprocessError):
            top = ""
        repo = Repo(Path(top)) if top else None
        _REPOS[folder] = repo if repo is not None and repo.head else None  # no commit yet: no history
    return _REPOS[folder]


def forget() -> None:
    """Close and drop every cached repository."""
    for repo in _REPOS.values():
        if repo is not None:
            repo.close()
    _REPOS.clear()


atexit.register(forget)  # the cat-file processes end with the interpreter
