"""One simulated RS-485 pair shared by several masters (`simulate --masters N`), the line the
redundancy tests put two gateways on: every node hears everything, and two masters talking at
once garble each other (a collision the simulator counts)."""

from __future__ import annotations

import time

import serial

from gateway.modbus.rtu import build_frame
from tests.support.shared_line import shared_line

READ = build_frame(1, bytes.fromhex("0330000002"))  # 3000H-3001H of drive 1
REPLY_BYTES = 9  # address, 03H, byte count 4, two words, CRC


def master(path: str) -> serial.Serial:
    return serial.Serial(path, 19200, timeout=0.3, exclusive=True)


def test_every_master_hears_the_other_and_the_drives_reply() -> None:
    with shared_line(2, "--address", "1") as line:
        first, second = (master(path) for path in line.paths)
        with first, second:
            first.write(READ)
            assert first.read(REPLY_BYTES)[:3] == bytes.fromhex("010304")
            heard = second.read(len(READ) + REPLY_BYTES)
            # The second master heard the first's request, then the drive's reply to it.
            assert heard[: len(READ)] == READ
            assert heard[len(READ) : len(READ) + 3] == bytes.fromhex("010304")
        stats = line.stats()
        assert stats["collisions"] == 0
        assert [m["frames"] for m in stats["masters"]] == [1, 0]
        assert stats["replies"] == 1


def test_two_masters_talking_at_once_collide_and_the_drive_stays_silent() -> None:
    with shared_line(2, "--address", "1") as line:
        first, second = (master(path) for path in line.paths)
        with first, second:
            first.write(READ)
            second.write(READ)  # well inside the first's 4.6 ms on the wire at 19200 baud
            time.sleep(0.2)
            # Each hears only the other's request: the drive saw a bad CRC and said nothing.
            assert first.read(100) == READ
            assert second.read(100) == READ
        stats = line.stats()
        assert stats["collisions"] == 1
        assert [m["collisions"] for m in stats["masters"]] == [1, 1]
        assert stats["replies"] == 0
        assert stats["crc_errors"] == 2


def test_a_master_that_waits_for_the_reply_does_not_collide() -> None:
    with shared_line(2, "--address", "1") as line:
        first, second = (master(path) for path in line.paths)
        with first, second:
            for _ in range(3):
                for talking in (first, second):
                    talking.reset_input_buffer()
                    talking.write(READ)
                    time.sleep(0.05)  # 4.6 ms out, 5 ms delay, 5.2 ms back: the line is quiet
                    assert talking.read(talking.in_waiting)[-REPLY_BYTES:][:3] == bytes.fromhex(
                        "010304"
                    )
        stats = line.stats()
        assert stats["collisions"] == 0
        assert [m["frames"] for m in stats["masters"]] == [3, 3]
        assert stats["replies"] == 6


def test_the_line_records_each_write_the_drives_got_and_who_sent_it() -> None:
    with shared_line(2, "--address", "1") as line:
        first, second = (master(path) for path in line.paths)
        with first, second:
            for talking, value in ((first, 5), (second, 6)):
                write = build_frame(1, bytes([0x06, 0x20, 0x02, 0x00, value]))
                talking.reset_input_buffer()  # what it heard of the other master
                talking.write(write)
                assert talking.read(len(write)) == write  # the drive's reply: an echo
                time.sleep(0.05)
            # Two writes at once collide: the drive got neither, and neither is recorded.
            first.write(build_frame(1, bytes.fromhex("0620020007")))
            second.write(build_frame(1, bytes.fromhex("0620020008")))
            time.sleep(0.2)
        answer = line.command("writes")
        assert answer == "ok [[1, 1, 8194, 5], [2, 1, 8194, 6]]", answer
        stats = line.stats()
        assert [m["writes"] for m in stats["masters"]] == [1, 1]
        assert stats["collisions"] == 1
