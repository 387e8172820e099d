"""The ingest loop's between-batch garbage collection (`runner.collect_between_batches`): cycles are still freed,
young ones when enough objects outlived batches, old ones by CPython's own generation counts."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Iterator

import pytest

from gateway.ingest import runner


class Node:
    """A weak-referenceable object for building reference cycles."""

    def __init__(self) -> None:
        self.other: object = self


@pytest.fixture
def manual_gc() -> Iterator[None]:
    """No automatic collections during the test (only the explicit ones under test); the settings come back."""
    enabled, threshold = gc.isenabled(), gc.get_threshold()
    gc.collect()
    gc.disable()
    try:
        yield
    finally:
        gc.set_threshold(*threshold)
        if enabled:
            gc.enable()


def garbage_cycle() -> weakref.ref[Node]:
    node = Node()
    return weakref.ref(node)  # `node` refers to itself: only the cycle collector frees it


def test_few_survivors_collect_nothing(manual_gc: None) -> None:
    ref = garbage_cycle()
    runner.collect_between_batches()
    assert ref() is not None  # under GC_YOUNG_BETWEEN new objects: no collection, so the cycle is still there


def test_young_cycles_are_freed_once_enough_objects_outlived_batches(manual_gc: None) -> None:
    ref = garbage_cycle()
    survivors = [[] for _ in range(runner.GC_YOUNG_BETWEEN)]  # noqa: F841 (kept alive: they are the survivors)
    runner.collect_between_batches()
    assert ref() is None
    assert gc.get_count()[0] < runner.GC_YOUNG_BETWEEN


def test_old_cycles_are_freed_by_the_generation_counts(manual_gc: None) -> None:
    node = Node()
    gc.collect(0)
    gc.collect(1)  # `node` lives on, now in the oldest generation
    ref = weakref.ref(node)
    del node
    _, gen1, gen2 = gc.get_threshold()
    keep = []
    for _ in range((gen1 + 1) * (gen2 + 1) + 1):
        keep.append([[] for _ in range(runner.GC_YOUNG_BETWEEN)])
        runner.collect_between_batches()
        if ref() is None:
            break
    assert ref() is None, "a full collection never ran"
