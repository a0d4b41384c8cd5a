"""Render a synthetic scene's cameras side by side, in lean worker processes.

``map_in_processes(fn, tasks, workers)`` is ``[fn(*t) for t in tasks]`` with the tasks dealt
round-robin to ``workers`` child interpreters started as ``python -m ftgspp.data.synthetic.pool
IN OUT``. A child imports only what ``fn`` needs: a ``multiprocessing`` spawn child would import
the parent's main module first (for ``study run``: torch, Hydra and MLflow, about 2 s each,
more than a small scene takes to render). ``fn`` must be a module-level function of an
importable module (not ``__main__``), and tasks and results must pickle; the pickles are
written to a private temporary folder and read back by this module only.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable


def map_in_processes(fn: Callable[..., Any], tasks: list[tuple], workers: int) -> list[Any]:
    """``[fn(*t) for t in tasks]``, in order, computed by ``workers`` child processes (in this
    process when ``workers`` is 1). A child's failure raises ``RuntimeError`` with its last
    line of output."""
    workers = max(1, min(workers, len(tasks)))
    if workers == 1:
        return [fn(*t) for t in tasks]
    env = {**os.environ, "PYTHONPATH": _import_path()}
    with tempfile.TemporaryDirectory(prefix="ftgspp-synth-") as tmp:
        procs = []
        try:
            for w in range(workers):
                src, dst = Path(tmp) / f"in{w}.pkl", Path(tmp) / f"out{w}.pkl"
                src.write_bytes(pickle.dumps((fn, tasks[w::workers])))
                procs.append((subprocess.Popen([sys.executable, "-m", __name__, str(src), str(dst)],
                                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                                               env=env), dst))
            results: list[list[Any]] = []
            for proc, dst in procs:
                _, err = proc.communicate()
                if proc.returncode != 0:
                    last = (err.strip().splitlines() or [f"exit status {proc.returncode}"])[-1]
                    raise RuntimeError(f"a scene-rendering worker failed: {last}")
                results.append(pickle.loads(dst.read_bytes()))
        finally:  # after a failure the other workers stop too: nothing writes after the error
            for proc, _ in procs:
                if proc.poll() is None:
                    proc.kill()
                    proc.communicate()
    return [results[k % workers][k // workers] for k in range(len(tasks))]


def _import_path() -> str:
    """The folder holding this ``ftgspp`` first, then the inherited ``PYTHONPATH``: a child
    imports the same code as this process, and nothing else is added to its path."""
    root = str(Path(__file__).resolve().parents[3])  # ftgspp/data/synthetic/pool.py -> the repository
    return os.pathsep.join([root, *filter(None, [os.environ.get("PYTHONPATH", "")])])


def _child(src: str, dst: str) -> None:
    fn, tasks = pickle.loads(Path(src).read_bytes())
    Path(dst).write_bytes(pickle.dumps([fn(*t) for t in tasks]))


if __name__ == "__main__":
    _child(sys.argv[1], sys.argv[2])
