"""Keep Python's cyclic garbage collector off the objects a worker keeps from run to run.

A study's worker holds hundreds of thousands of long-lived objects (torch, Numba, Hydra,
MLflow, pandas, matplotlib). Every full collection walks all of them: about 0.3 s each,
one or more a run, and once more when the worker exits (a study's last ~4 s were both
workers and then the study process in that final collection). ``settled_heap`` collects once
before and once after a run and then freezes what is left (``gc.freeze``): frozen objects are
never walked again, so later collections, and the one at exit, see only what the current run
allocated. Garbage is collected before each freeze, so nothing a run dropped is kept; a run
that raises is not followed by a freeze (its traceback holds the run's frames in reference
cycles, which a freeze would keep for good).

    with settled_heap():
        result = train_one(cfg)   # its locals (scene, model) gone before the block ends

It changes no computed value: the collector only frees unreachable objects.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


def settle() -> None:
    """Collect the garbage, then freeze every object still alive (``gc.freeze``)."""
    gc.collect()
    gc.freeze()


@contextmanager
def settled_heap() -> Iterator[None]:
    """``settle()`` before the block and after it when it does not raise."""
    settle()
    yield
    settle()
