"""After setup a service's heap is settled: what setup made is out of the collector's
sight, and an epoch's short-lived messages do not set off a collection every few hundred."""

from __future__ import annotations

import gc
from collections.abc import Iterator

import pytest

from shell.service import YOUNG_OBJECTS, settle_heap


@pytest.fixture
def restored_collector() -> Iterator[None]:
    threshold = gc.get_threshold()
    # Python's default: a service started by an earlier test settled this process's heap
    gc.set_threshold(700, 10, 10)
    yield
    gc.unfreeze()
    gc.set_threshold(*threshold)


def _collections_while_allocating(objects: int) -> int:
    started: list[int] = []

    def count(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            started.append(info["generation"])

    gc.callbacks.append(count)
    try:
        kept = [[i] for i in range(objects)]  # containers: each one counts as an allocation
    finally:
        gc.callbacks.remove(count)
    assert len(kept) == objects
    return len(started)


@pytest.mark.usefixtures("restored_collector")
def test_a_settled_heap_collects_nothing_while_an_epoch_allocates() -> None:
    objects = YOUNG_OBJECTS // 2
    assert _collections_while_allocating(objects) > 0
    settle_heap()
    assert gc.get_freeze_count() > 0
    assert _collections_while_allocating(objects) == 0
