"""Where a run came from: git commit of the code, the trainer fingerprint, device and backend.

``git_sha`` is read-only ``git rev-parse`` / ``git status`` ("unknown" outside a checkout).
``trainer_fingerprint`` hashes the contents of the files that decide a run's numbers for a
given config (``ftgspp/**/*.py`` and ``conf/**/*.yaml``, but not ``ftgspp/bench/``: the
benchmarks never run inside training and do not decide a run's bits): two checkouts with the same
fingerprint train the same bits in the same determinism domain, whatever else (harness,
docs, reports) differs. Reports name it, and ``study check`` uses it to say why runs differ.

``same_bits(trainer)`` is ``trainer`` and every earlier fingerprint that ``same_bits.yaml`` (next to
this module) records as training the same bits: a change to trainer files that ``study check``
showed leaves the runs it retrained bit for bit as they were (a refactor, a new method beside the
old ones). Runs of those trainers count as ``trainer``'s wherever currency is decided (report
stale notes, ``make reports``' plan, ``study run --rerun-stale``). A record is added only with
that check's result as its evidence.

``checkout_fingerprint`` is the fingerprint a report compares its runs with: this checkout's,
unless ``FTGSPP_CHECKOUT_FINGERPRINT`` names another. Only ``scripts/report_parity.py`` sets it:
a refactor that moves a trainer file changes the fingerprint by design, and the parity check
asks what two harness versions write about the same runs for the same trainer. Runs always
record the real fingerprint (``trainer_fingerprint``).
"""

from __future__ import annotations

import functools
import hashlib
import os
import subprocess
from pathlib import Path
from typing import Iterable

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
            # Generated reports are outputs, not code: writing one must not make the next "dirty".
            ["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no", "--", ".", ":(exclude)reports"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        return sha.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


TRAINER_FILES = (("ftgspp", "*.py"), ("conf", "*.yaml"))
NOT_TRAINER = (("ftgspp", "bench"),)  # folders under TRAINER_FILES that training never imports


@functools.lru_cache(maxsize=1)
def trainer_fingerprint(root: Path = REPO) -> str:
    """12 hex digits over the relative paths and contents of the trainer's code and configs."""
    h = hashlib.sha256()
    for folder, pattern in TRAINER_FILES:
        for path in sorted((root / folder).rglob(pattern)):
            rel = path.relative_to(root).parts
            if "__pycache__" not in rel and not any(rel[: len(skip)] == skip for skip in NOT_TRAINER):
                h.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()[:12]


SAME_BITS = Path(__file__).with_name("same_bits.yaml")


def same_bits_records(path: Path | None = None) -> list[dict]:
    """The records of ``same_bits.yaml`` (``trainer``, ``same_bits_as``, ``change``, ``evidence``, ``date``)."""
    return list(_records(Path(path or SAME_BITS)))


@functools.lru_cache(maxsize=8)
def _records(path: Path) -> tuple[dict, ...]:
    """The file read once per process (``study run`` asks about every finished run)."""
    import yaml

    return tuple(yaml.safe_load(path.read_text()) or []) if path.is_file() else ()


def same_bits(trainer: str, path: Path | None = None) -> frozenset[str]:
    """``trainer`` and every earlier trainer fingerprint recorded to train the same bits as it,
    following the records back (A -> B -> C): the trainers whose runs count as ``trainer``'s."""
    return _same_bits(trainer, Path(path or SAME_BITS))


@functools.lru_cache(maxsize=64)
def _same_bits(trainer: str, path: Path) -> frozenset[str]:
    earlier: dict[str, set[str]] = {}
    for rec in _records(path):
        earlier.setdefault(str(rec["trainer"]), set()).add(str(rec["same_bits_as"]))
    found, todo = {trainer}, [trainer]
    while todo:
        for prior in earlier.get(todo.pop(), ()):
            if prior not in found:
                found.add(prior)
                todo.append(prior)
    return frozenset(found)


def all_current(fingerprints: Iterable[str], current: str) -> bool:
    """Whether every run of these trainer ``fingerprints`` counts as ``current``'s (``same_bits``)."""
    return set(fingerprints) <= same_bits(current)


CHECKOUT_FINGERPRINT = "FTGSPP_CHECKOUT_FINGERPRINT"


def checkout_fingerprint() -> str:
    """The trainer fingerprint reports call "this checkout's" (see the module docstring)."""
    return os.environ.get(CHECKOUT_FINGERPRINT) or trainer_fingerprint()


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
