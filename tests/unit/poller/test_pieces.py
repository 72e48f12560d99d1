"""A poll block cut into pieces while SCADA reads wait (`PollBlock.pieces_while_reads_wait`)."""

from __future__ import annotations

import pytest

from gateway.poller.plan import WORDS_WHILE_READS_WAIT, PollBlock
from gateway.profile.point_types import Table


@pytest.mark.parametrize(
    ("count", "sizes"),
    [(12, [6, 6]), (16, [8, 8]), (17, [6, 6, 5]), (9, [5, 4]), (8, [8]), (1, [1])],
)
def test_a_long_block_goes_as_near_equal_pieces_in_order(count: int, sizes: list[int]) -> None:
    block = PollBlock(0x3000, count, Table.INPUT)
    pieces = block.pieces_while_reads_wait()
    assert [piece.count for piece in pieces] == sizes
    assert all(piece.count <= WORDS_WHILE_READS_WAIT for piece in pieces)
    assert all(piece.table is Table.INPUT for piece in pieces)
    # Back to back from the block's start: together they read exactly its words.
    starts = [piece.start for piece in pieces]
    assert starts == [0x3000 + sum(sizes[:n]) for n in range(len(sizes))]
    assert pieces[-1].start + pieces[-1].count == block.start + block.count


def test_bits_are_read_whole() -> None:
    coils = PollBlock(0, 200, Table.COIL)  # 200 bits: 25 bytes on the wire, not 200 words
    assert coils.pieces_while_reads_wait() == (coils,)
