"""``run.heap``: the collector is settled around a process's first run, without keeping garbage."""

from __future__ import annotations

import gc
import weakref

import pytest

from harness.run import heap
from harness.run.heap import settle, settled_heap


class Node:
    """A reference cycle: freed only by the cyclic collector, never by reference counting."""

    def __init__(self) -> None:
        self.me = self


@pytest.fixture(autouse=True)
def fresh_process(monkeypatch):
    """As in a new worker: nothing frozen, no run settled yet."""
    gc.unfreeze()
    monkeypatch.setattr(heap, "_settled", False)
    yield
    gc.unfreeze()


def dropped_cycle() -> weakref.ref:
    node = Node()
    return weakref.ref(node)


def test_garbage_from_before_the_first_run_is_freed_not_frozen():
    before = dropped_cycle()
    with settled_heap():
        assert before() is None  # collected before the freeze, so not kept for good
        assert gc.get_freeze_count() > 0


def test_the_first_run_is_followed_by_a_freeze_of_what_it_left_alive():
    with settled_heap():
        during = dropped_cycle()
        kept = Node()  # alive at the end of the run, as a module cache the run filled
        assert any(o is kept for o in gc.get_objects())  # the collector's generations hold it
    assert during() is None  # the run's garbage was collected before the freeze
    assert not any(o is kept for o in gc.get_objects())  # ...and what it left alive frozen
    assert kept.me is kept


def test_later_runs_freeze_nothing_so_their_garbage_stays_collectable():
    with settled_heap():
        pass
    frozen = gc.get_freeze_count()
    holder = []
    with settled_heap():  # a later run: e.g. Hydra's job configs, alive until the job returns
        node = Node()
        holder.append(node)
        ref = weakref.ref(node)
        del node
    assert gc.get_freeze_count() <= frozen  # nothing added (frozen objects freed since may leave)
    assert any(o is holder[0] for o in gc.get_objects())
    holder.clear()  # the job returns: its configs become cyclic garbage
    gc.collect()
    assert ref() is None  # not frozen, so collected


def test_a_later_collection_does_not_walk_frozen_objects():
    many = [Node() for _ in range(50_000)]  # long-lived, as a worker's imports leave them
    settle()
    assert len(gc.get_objects()) < len(many)  # no generation of the collector holds them now
    assert all(n.me is n for n in many)


def test_a_first_run_that_raises_is_not_followed_by_a_freeze():
    with pytest.raises(RuntimeError):
        with settled_heap():
            gc.unfreeze()
            raise RuntimeError("crashed run")
    assert gc.get_freeze_count() == 0  # its traceback's cycles stay collectable
    assert heap._settled is False  # the next run settles instead
