"""``run.heap``: the collector is settled around a run without keeping anything a run dropped."""

from __future__ import annotations

import gc
import weakref

import pytest

from harness.run.heap import settle, settled_heap


class Node:
    """A reference cycle: freed only by the cyclic collector, never by reference counting."""

    def __init__(self) -> None:
        self.me = self


@pytest.fixture(autouse=True)
def unfrozen():
    gc.unfreeze()
    yield
    gc.unfreeze()


def dropped_cycle() -> weakref.ref:
    node = Node()
    return weakref.ref(node)


def test_garbage_from_before_the_run_is_freed_not_frozen():
    before = dropped_cycle()
    with settled_heap():
        assert before() is None  # collected before the freeze, so not kept for good
        assert gc.get_freeze_count() > 0


def test_garbage_of_the_run_is_freed_and_what_lives_is_frozen():
    with settled_heap():
        during = dropped_cycle()
        alive = Node()
    assert during() is None
    assert gc.get_freeze_count() > 0
    assert alive.me is alive


def test_a_later_collection_does_not_walk_frozen_objects():
    many = [Node() for _ in range(50_000)]  # long-lived, as a worker's imports leave them
    settle()
    assert len(gc.get_objects()) < len(many)  # no generation of the collector holds them now
    assert all(n.me is n for n in many)


def test_a_run_that_raises_is_not_followed_by_a_freeze():
    with pytest.raises(RuntimeError):
        with settled_heap():
            gc.unfreeze()
            raise RuntimeError("crashed run")
    assert gc.get_freeze_count() == 0  # its traceback's cycles stay collectable
