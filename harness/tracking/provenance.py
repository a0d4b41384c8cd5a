"""Where a run came from: git commit of the code, the resolved device and render backend.

Read-only: ``git rev-parse`` / ``git status``; "unknown" outside a git checkout.
"""

from __future__ import annotations

import functools
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


@functools.lru_cache(maxsize=1)
def git_sha() -> str:
    """Commit of the harness code, with ``-dirty`` if tracked files changed since."""
    try:
        sha = subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10
        )
        if sha.returncode != 0:
            return "unknown"
        dirty = subprocess.run(
            ["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def resolve_device(device: str) -> str:
    """The device a run on ``device`` trains on (``ftgspp.runtime.device``); unchanged when the
    trainer will refuse it (it reports that error itself)."""
    from ftgspp.errors import InputError
    from ftgspp.runtime.device import resolve_device as resolve

    try:
        return str(resolve(device))
    except InputError:
        return device


def resolve_backend(backend: str, device: str) -> str:
    """The render backend ``auto`` picks on ``device`` (as the trainer will); else unchanged."""
    if backend != "auto":
        return backend
    try:
        import torch

        from ftgspp.render import resolve_backend as pick

        return pick(backend, torch.device(device))
    except Exception:  # a backend that cannot even be probed: record what was asked
        return backend
