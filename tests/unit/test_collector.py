"""The cyclic collector kept out of timed work: paused over a measurement, start-up frozen."""

from __future__ import annotations

import gc

from gateway.collector import collector_paused, settle_startup_objects


def test_no_collection_inside_a_paused_block_and_the_collector_back_after() -> None:
    collections: list[int] = []

    def counted(phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            collections.append(info["generation"])

    gc.callbacks.append(counted)
    try:
        with collector_paused():
            collections.clear()  # the one just before the block
            for _ in range(50_000):  # garbage enough for many collections, were it enabled
                cycle: list[object] = []
                cycle.append(cycle)
            assert not gc.isenabled()
            assert collections == []
        assert gc.isenabled()
    finally:
        gc.callbacks.remove(counted)


def test_a_collector_disabled_before_the_block_stays_disabled() -> None:
    gc.disable()
    try:
        with collector_paused():
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_start_up_objects_are_out_of_the_collectors_sight() -> None:
    before = gc.get_freeze_count()
    kept = [[n] for n in range(1000)]  # what a start-up builds and keeps
    try:
        settle_startup_objects()
        assert gc.get_freeze_count() >= before + len(kept)
    finally:
        gc.unfreeze()
