"""The store's room on its disk: max_mb, or what the disk has beyond the reserve; full when
others took half the reserve, or when too little is left to be worth trimming for."""

from __future__ import annotations

from gateway.store.space import Room

KB = 1024
MB = 1024 * KB


def test_a_disk_with_room_gives_max_mb() -> None:
    room = Room(own=1 * MB, free=10_000 * MB, reserve=64 * MB, max_bytes=64 * MB)
    assert (room.budget, room.full) == (64 * MB, False)


def test_a_small_disk_gives_what_it_has_beyond_the_reserve() -> None:
    room = Room(own=1 * MB, free=1 * MB, reserve=256 * KB, max_bytes=64 * MB)
    assert (room.budget, room.full) == (2 * MB - 256 * KB, False)


def test_the_store_may_dip_into_half_the_reserve_but_no_further() -> None:
    room = Room(own=1 * MB, free=129 * KB, reserve=256 * KB, max_bytes=64 * MB)
    assert not room.full  # the store's own write, before its trim and checkpoint
    room = Room(own=1 * MB, free=127 * KB, reserve=256 * KB, max_bytes=64 * MB)
    assert room.full
    assert "127 kB free" in room.why_full("/var/lib/invt-gateway/events.db")


def test_a_small_store_on_a_disk_others_filled_is_not_trimmed_to_nothing() -> None:
    room = Room(own=100 * KB, free=140 * KB, reserve=256 * KB, max_bytes=64 * MB)
    assert room.budget < 0
    assert room.full


def test_a_store_bound_smaller_than_the_minimum_is_not_full() -> None:
    room = Room(own=0, free=1000 * MB, reserve=50 * MB, max_bytes=52 * KB)  # max_mb: 0.05
    assert (room.budget, room.full) == (52 * KB, False)
