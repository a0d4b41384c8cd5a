"""Keep Python's cyclic garbage collector off the objects a worker keeps from run to run.

A study's worker holds hundreds of thousands of long-lived objects (torch, Numba, Hydra,
MLflow, pandas, matplotlib, most of them imported during its first run). Every full
collection walks all of them: 0.36–0.49 s each, about 0.4 s a run, and once more when the
worker exits (a study's last ~4 s were both workers in that final collection). ``settled_heap``
collects and then freezes (``gc.freeze``) before and after a process's *first* run only:
frozen objects are never walked again, so later collections, and the one at exit, see little
more than what the current run allocated.

Only the first run: a freeze also catches the objects of the job that is still running (Hydra's
configs of the run, which reference their parents and become cyclic garbage once the job
returns), and frozen garbage is never collected. Freezing once bounds that to one job's objects
(1–2 MB a worker); freezing after every run would keep them from every run. Garbage is
collected before each freeze, and a first run that raises is not followed by one (its
traceback's cycles hold the run's frames).

    with settled_heap():
        result = train_one(cfg)   # its locals (scene, model) gone before the block ends

It changes no computed value: the collector only frees unreachable objects.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager

_settled = False  # whether this process's first run has been settled


def settle() -> None:
    """Collect the garbage, then freeze every object still alive (``gc.freeze``)."""
    gc.collect()
    gc.freeze()


@contextmanager
def settled_heap() -> Iterator[None]:
    """``settle()`` before the block and after it (unless it raises), the first time a process
    enters it; a no-op after that."""
    global _settled
    if _settled:
        yield
        return
    settle()
    yield
    settle()
    _settled = True
