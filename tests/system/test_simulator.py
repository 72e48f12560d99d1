"""The simulated INVT line through a real pty, read and written with pyserial as a master does."""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import select
import signal
import subprocess
import sys
import threading
import time
import tty
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from gateway import timerfd
from gateway.instruments.simulator import SimulatedLine
from gateway.instruments.simulator.control import USAGE, run_control_command
from gateway.libc import process_libc
from gateway.modbus.crc import crc_ok
from gateway.modbus.rtu import build_frame
from tests.support.protocol_frames import PROTOCOL_EXCHANGES
from tests.support.serial_master import exchange, read_reply

pytestmark = pytest.mark.line(addresses=[1, 2, 3], wire_time=False, response_delay_ms=0)

READ_STATE_WORD_1 = "01 03 21 00 00 01 8E 36"
STOPPED_REPLY = "01 03 02 00 03 F8 45"


def frame(address: int, pdu_hex: str) -> bytes:
    return build_frame(address, bytes.fromhex(pdu_hex))


def silent(port: serial.Serial, wait_s: float = 0.15) -> bool:
    """True when nothing at all arrives within `wait_s`.

    It waits and looks rather than changing `port.timeout`: on some kernels a pty refuses any
    termios change once parity is asked for (see `reopen`), and pyserial applies a timeout
    change through termios."""
    time.sleep(wait_s)  # asserting an absence: nothing may arrive in this window
    return port.in_waiting == 0


def read_until_quiet(port: serial.Serial, first_s: float = 2.0, quiet_s: float = 0.1) -> bytes:
    """What came for a request whose reply has no length to wait for (a spoilt one): its first
    byte within `first_s` (a busy machine may be slow to answer; a fixed 0.1 s failed once in
    a CI run), then everything until `quiet_s` of silence."""
    received = b""
    deadline = time.monotonic() + first_s
    while not received and time.monotonic() < deadline:
        received = port.read(port.in_waiting or 1)  # blocks up to the port's timeout for one
    while received:
        time.sleep(quiet_s)
        more = port.read(port.in_waiting)
        if not more:
            break
        received += more
    return received


def open_port(line: SimulatedLine, baudrate: int = 115200) -> serial.Serial:
    return serial.Serial(line.path, baudrate, parity="E", timeout=1)


@pytest.fixture
def port(line: SimulatedLine) -> Iterator[serial.Serial]:
    with open_port(line) as opened:
        yield opened


# ---------------------------------------------------------------- the manual's frames


def test_every_protocol_frame_is_reproduced_byte_exact() -> None:
    with (
        SimulatedLine(
            addresses=[1, 2, 3], baudrate=19200, parity="E", fault_history={3: [35] * 6}
        ) as line,
        serial.Serial(line.path, 19200, parity="E", timeout=1) as port,
    ):
        for request_hex, reply_hex in PROTOCOL_EXCHANGES:
            request, expected = bytes.fromhex(request_hex), bytes.fromhex(reply_hex)
            reply = exchange(port, request)
            assert reply == expected, f"{request_hex} answered {reply.hex(' ').upper()}"
            time.sleep(0.003)  # t3.5 before the next request, as a master must
        assert line.stats["requests"] == len(PROTOCOL_EXCHANGES)
        assert line.stats["replies"] == len(PROTOCOL_EXCHANGES)
        assert line.stats["gap_violations"] == 0


# ---------------------------------------------------------------- drive behaviour on the line


def test_run_ramp_and_stop(line: SimulatedLine, port: serial.Serial) -> None:
    exchange(port, frame(1, "10 00 0B 00 02 04 00 02 00 02"))  # P00.11 = P00.12 = 0.2 s
    assert exchange(port, frame(1, "10 20 00 00 02 04 00 01 09 C4")) == frame(1, "10 20 00 00 02")
    assert exchange(port, frame(1, "03 21 00 00 01")) == frame(1, "03 02 00 01")  # forward
    time.sleep(0.3)  # the simulated motor's ramp: 25.00 Hz is reached in 0.1 s
    running = exchange(port, frame(1, "03 30 00 00 06"))
    assert running[3:7] == bytes.fromhex("09 C4 09 C4")  # running and set frequency 25.00 Hz
    assert running[9:11] == (190).to_bytes(2, "big")  # output voltage: 380 V x 25/50
    exchange(port, frame(1, "06 20 00 00 05"))  # stop
    time.sleep(0.3)  # the simulated motor's ramp down (0.1 s) is the thing under test
    assert exchange(port, frame(1, "03 21 00 00 01")) == frame(1, "03 02 00 03")
    assert exchange(port, frame(1, "03 30 00 00 01")) == frame(1, "03 02 00 00")


def test_fault_injected_then_reset_over_modbus(line: SimulatedLine, port: serial.Serial) -> None:
    line.inject_fault(2, 35)
    # State word 1: fault; state word 2: not ready (GD350: "=0: Not ready to run", page -282-
    # of its communication chapter), communication; STo.
    assert exchange(port, frame(2, "03 21 00 00 03")) == frame(2, "03 06 00 04 00 40 00 23")
    assert exchange(port, frame(2, "03 50 00 00 01")) == frame(2, "03 02 00 23")
    assert exchange(port, frame(2, "06 20 00 00 01")) == frame(2, "86 01")  # can't run faulty
    assert exchange(port, frame(2, "06 20 00 00 07")) == frame(2, "06 20 00 00 07")  # reset
    assert exchange(port, frame(2, "03 21 00 00 01")) == frame(2, "03 02 00 03")
    assert exchange(port, frame(2, "03 07 1B 00 01")) == frame(2, "03 02 00 23")  # history kept


def test_clear_fault_from_the_test_side(line: SimulatedLine, port: serial.Serial) -> None:
    line.inject_fault(1, 18)
    line.clear_fault(1)
    assert exchange(port, frame(1, "03 21 02 00 01")) == frame(1, "03 02 00 00")


def test_ram_only_write_does_not_wear_the_eeprom(line: SimulatedLine, port: serial.Serial) -> None:
    assert exchange(port, frame(1, "06 80 0B 00 32")) == frame(1, "06 80 0B 00 32")  # P00.11
    assert exchange(port, frame(1, "03 00 0B 00 01")) == frame(1, "03 02 00 32")
    assert exchange(port, frame(1, "03 80 0B 00 01")) == frame(1, "83 02")  # write-only
    with line.lock:
        assert line.drives[1].ram_writes == 1
        assert line.drives[1].eeprom_writes == 0
    exchange(port, frame(1, "06 00 0B 00 33"))
    with line.lock:
        assert line.drives[1].eeprom_writes == 1


def test_unknown_function_ends_on_silence_and_gets_01h(port: serial.Serial) -> None:
    assert exchange(port, frame(1, "04 00 00 00 01")) == frame(1, "84 01")


def test_frame_of_the_wrong_length_gets_06h(port: serial.Serial) -> None:
    # A 03H request with one byte too many but a good CRC: INVT's "data frame error".
    assert exchange(port, frame(1, "03 21 00 00 01 00")) == frame(1, "83 06")


def test_bad_crc_is_ignored_and_counted(line: SimulatedLine, port: serial.Serial) -> None:
    request = bytearray.fromhex(READ_STATE_WORD_1)
    request[-1] ^= 0x01
    port.write(request)
    assert silent(port)
    assert line.stats["crc_errors"] == 1
    assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)


def test_garbage_then_silence_then_a_request_is_answered(
    line: SimulatedLine, port: serial.Serial
) -> None:
    port.write(b"\x01\x03\x55\xaa\x00")  # looks like the start of a read, isn't one
    time.sleep(0.02)  # the thing under test: silence after the garbage, far longer than t3.5
    assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)
    assert line.stats["crc_errors"] == 1


def test_back_to_back_requests_in_one_write_are_both_answered(port: serial.Serial) -> None:
    port.write(frame(1, "03 21 00 00 01") + frame(2, "03 21 03 00 01"))
    assert read_reply(port, 8) == frame(1, "03 02 00 03")
    assert read_reply(port, 8) == frame(2, "03 02 01 A0")


def test_dead_and_unknown_addresses_are_silent(line: SimulatedLine, port: serial.Serial) -> None:
    line.set_dead(2, True)
    port.write(frame(2, "03 21 00 00 01"))
    assert silent(port)
    port.write(frame(9, "03 21 00 00 01"))  # nobody at 9
    assert silent(port)
    assert line.stats["ignored"] == 2
    line.set_dead(2, False)
    assert exchange(port, frame(2, "03 21 00 00 01")) == frame(2, "03 02 00 03")


def test_broadcast_is_acted_on_by_every_drive_and_answered_by_none(
    line: SimulatedLine, port: serial.Serial
) -> None:
    port.write(frame(0, "06 00 05 03 09"))  # P00.05 = 7.77 Hz everywhere
    assert silent(port)
    for address in (1, 2, 3):
        assert exchange(port, frame(address, "03 00 05 00 01")) == frame(address, "03 02 03 09")
    assert line.stats["broadcasts"] == 1


def test_late_reply_from_one_address(line: SimulatedLine, port: serial.Serial) -> None:
    line.set_reply_delay(1, 120)
    started = time.monotonic()
    assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)
    assert time.monotonic() - started >= 0.12
    line.set_reply_delay(1, 0)
    started = time.monotonic()
    exchange(port, bytes.fromhex(READ_STATE_WORD_1))
    assert time.monotonic() - started < 0.1


def test_p14_03_written_over_modbus_delays_the_replies(port: serial.Serial) -> None:
    exchange(port, frame(1, "06 0E 03 00 3C"))  # P14.03 = 60 ms
    started = time.monotonic()
    exchange(port, bytes.fromhex(READ_STATE_WORD_1))
    assert time.monotonic() - started >= 0.06


# ---------------------------------------------------------------- line faults


@pytest.mark.parametrize("kind", ["crc", "truncated", "extra_bytes", "wrong_address"])
def test_spoilt_replies(line: SimulatedLine, port: serial.Serial, kind: str) -> None:
    line.set_line_faults(rate=1.0, kinds={kind}, seed=1)
    port.write(bytes.fromhex(READ_STATE_WORD_1))
    received = read_until_quiet(port)
    good = bytes.fromhex(STOPPED_REPLY)
    if kind == "crc":
        assert len(received) == len(good)
        assert not crc_ok(received)
    elif kind == "truncated":
        assert 0 < len(received) < len(good)
        assert good.startswith(received)
    elif kind == "extra_bytes":
        assert received.startswith(good)
        assert len(received) > len(good)
    else:
        assert crc_ok(received)
        assert received[0] != 1
        assert received[1:-2] == good[1:-2]
    assert line.stats["faults_injected"] == 1
    assert line.stats["faults_by_kind"] == {kind: 1}


def test_silence_and_late_faults(line: SimulatedLine, port: serial.Serial) -> None:
    line.set_line_faults(rate=1.0, kinds={"silence"}, seed=1)
    port.write(bytes.fromhex(READ_STATE_WORD_1))
    assert silent(port)
    line.set_line_faults(rate=1.0, kinds={"late"}, seed=1, late_ms=150)
    started = time.monotonic()
    assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)
    assert time.monotonic() - started >= 0.15


def test_fault_rate_is_roughly_kept_and_reproducible(
    line: SimulatedLine, port: serial.Serial
) -> None:
    def spoilt_count() -> int:
        line.set_line_faults(rate=0.25, kinds={"crc"}, seed=42)
        before = line.stats["faults_injected"]
        for _ in range(60):
            exchange(port, bytes.fromhex(READ_STATE_WORD_1))
        return int(line.stats["faults_injected"] - before)

    first = spoilt_count()
    assert 5 <= first <= 25
    assert spoilt_count() == first  # the same seed spoils the same replies


def test_noise_written_by_the_line_reaches_the_master(
    line: SimulatedLine, port: serial.Serial
) -> None:
    line.write_raw(b"\x55\xaa")
    assert port.read(2) == b"\x55\xaa"


# ---------------------------------------------------------------- timing


@pytest.mark.parametrize("wait", ["timerfd", "select"])
def test_wire_time_at_9600_baud(wait: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Whichever way the serving thread waits for a reply's time: a timerfd in epoll, or
    select's own timeout where the system has no timerfd."""
    if wait == "select":
        monkeypatch.setattr(timerfd, "libc", lambda: None)  # as on a system without timerfd
    elif timerfd.libc() is None:
        pytest.skip("no timerfd on this system")
    # 8 request + 7 reply bytes of 11 bits at 9600 baud: 17.2 ms on the wire, plus 5 ms delay.
    with (
        SimulatedLine([1], baudrate=9600, wire_time=True, response_delay_ms=5.0) as line,
        serial.Serial(line.path, 9600, parity="E", timeout=1) as port,
    ):
        durations = []
        for _ in range(3):
            started = time.monotonic()
            assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)
            durations.append(time.monotonic() - started)
            time.sleep(0.01)  # more than t3.5 before the next request, as a master must
        assert min(durations) >= 15 * 11 / 9600 + 0.005
        assert max(durations) < 0.1
        # Woken for each reply when it was due, not a wait's worth later (a timer armed in the
        # wrong unit, or not at all, is tens of milliseconds late or never; a machine busy with
        # other work makes a wake-up a few milliseconds late, which is no fault of the line).
        late = {float(bound): count for bound, count in line.stats["reply_late_buckets"]}
        assert late[0.01] == late[float("inf")] == 3


def test_a_line_that_does_not_spin_answers_right_and_never_early() -> None:
    """`wake_early_s=0` (what `bench` nears with many lines: they share one line's spin): the
    line sleeps until a reply is due instead of spinning out the last microseconds."""
    with (
        SimulatedLine([1], baudrate=9600, response_delay_ms=5.0, wake_early_s=0.0) as line,
        serial.Serial(line.path, 9600, parity="E", timeout=1) as port,
    ):
        for _ in range(3):
            started = time.monotonic()
            assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)
            assert time.monotonic() - started >= 15 * 11 / 9600 + 0.005
            time.sleep(0.01)
        assert line.stats["replies"] == 3


def test_no_wire_time_answers_at_once() -> None:
    with (
        SimulatedLine([1], baudrate=9600, wire_time=False, response_delay_ms=0) as line,
        serial.Serial(line.path, 9600, parity="E", timeout=1) as port,
    ):
        started = time.monotonic()
        exchange(port, bytes.fromhex(READ_STATE_WORD_1))
        assert time.monotonic() - started < 0.0172


def test_gap_violations_are_counted() -> None:
    t35 = 3.5 * 11 / 9600  # 4.0 ms at 9600 8E1
    with (
        SimulatedLine([1], baudrate=9600, wire_time=True, response_delay_ms=5.0) as line,
        serial.Serial(line.path, 9600, parity="E", timeout=1) as port,
    ):
        exchange(port, bytes.fromhex(READ_STATE_WORD_1))
        exchange(port, bytes.fromhex(READ_STATE_WORD_1))  # at once after the reply: too soon
        assert line.stats["gap_violations"] == 1
        assert line.stats["min_gap_s"] < t35
        time.sleep(2 * t35)  # the thing under test: a master that keeps the gap
        exchange(port, bytes.fromhex(READ_STATE_WORD_1))
        assert line.stats["gap_violations"] == 1
        # Two requests in one write: the second starts before the first has left the wire.
        time.sleep(2 * t35)  # a clean start for the next case
        port.write(frame(1, "03 21 00 00 01") * 2)
        read_reply(port, 8)
        read_reply(port, 8)
        assert line.stats["gap_violations"] == 2
        assert line.stats["min_gap_s"] < 0


def _counted(buckets: list[tuple[str, int]], at_most_s: float = float("inf")) -> int:
    """Observations at or below `at_most_s` in a cumulative (`le`, count) histogram."""
    return max((count for le, count in buckets if float(le) <= at_most_s), default=0)


def test_the_line_tells_how_late_its_drives_answered_and_what_silence_they_heard() -> None:
    """What the benchmark splits a transaction's overhead by: every reply's lateness after the
    moment it was due, and the silence beyond t3.5 the drives heard before each request that
    followed a reply (a master's pause shows there whole)."""
    t35 = 3.5 * 11 / 9600
    with (
        SimulatedLine([1], baudrate=9600, wire_time=True, response_delay_ms=5.0) as line,
        serial.Serial(line.path, 9600, parity="E", timeout=1) as port,
    ):
        exchange(port, bytes.fromhex(READ_STATE_WORD_1))
        assert _counted(line.stats["reply_late_buckets"]) == 1
        assert _counted(line.stats["heard_gap_buckets"]) == 0  # no request after a reply yet
        time.sleep(t35 + 0.02)  # the thing under test: a master's pause of 20 ms beyond t3.5
        exchange(port, bytes.fromhex(READ_STATE_WORD_1))
        stats = line.stats
    assert _counted(stats["reply_late_buckets"]) == 2
    # Answered on time: the line spins out the last few hundred microseconds before a reply.
    assert _counted(stats["reply_late_buckets"], 0.005) == 2
    heard = stats["heard_gap_buckets"]
    assert _counted(heard) == 1
    assert _counted(heard, 0.01) == 0  # the 20 ms pause, in the last bucket (beyond 10 ms)
    assert heard[-1][0] == "+Inf"


def test_a_relays_delays_are_silence_on_the_wire_and_left_out_of_what_the_drives_heard() -> None:
    """A relay of 20 ms each way: a master that asks again at once after a reply still leaves
    the wire silent for the two delays (no gap violation), and the silence the drives heard
    beyond t3.5 leaves those configured delays out (the bench counts them in the maximum)."""
    with (
        SimulatedLine([1], baudrate=9600, wire_time=True, relay_s=0.02) as line,
        serial.Serial(line.path, 9600, parity="E", timeout=1) as port,
    ):
        exchange(port, bytes.fromhex(READ_STATE_WORD_1))
        exchange(port, bytes.fromhex(READ_STATE_WORD_1))  # at once after the reply
        stats = line.stats
    assert stats["gap_violations"] == 0
    heard = stats["heard_gap_buckets"]
    assert _counted(heard) == 1
    assert _counted(heard, 0.01) == 1  # not the 40 ms of the relay


# ---------------------------------------------------------------- the port itself


def test_unplug_and_replug_behind_a_link(tmp_path: Path) -> None:
    link = tmp_path / "usb-FTDI_RS485-if00-port0"
    with SimulatedLine([1], baudrate=115200, wire_time=False, link=str(link)) as line:
        assert line.path == str(link)
        with serial.Serial(str(link), 115200, parity="E", timeout=1) as port:
            assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)
            line.unplug()
            assert not link.exists()
            with pytest.raises(serial.SerialException, match="Input/output error"):
                port.write(bytes.fromhex(READ_STATE_WORD_1))  # EIO, like a pulled USB adapter
        line.replug()
        assert link.is_symlink()
        with serial.Serial(str(link), 115200, parity="E", timeout=1) as port:
            assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)
    assert not link.exists()  # stop removes the link it made


def test_serving_an_existing_serial_device() -> None:
    # A pty pair stands in for a USB adapter: the line opens its slave side as a device, the
    # test is the master on the other end.
    master, slave = os.openpty()
    tty.setraw(master)
    try:
        device = os.ttyname(slave)
        with SimulatedLine([1], baudrate=115200, wire_time=False, device=device) as line:
            assert line.path == device
            os.write(master, bytes.fromhex(READ_STATE_WORD_1))
            received = b""
            deadline = time.monotonic() + 2
            while len(received) < 7 and time.monotonic() < deadline:
                if select.select([master], [], [], 0.1)[0]:
                    received += os.read(master, 64)
            assert received == bytes.fromhex(STOPPED_REPLY)
    finally:
        os.close(master)
        os.close(slave)


def test_the_gateway_closing_its_port_does_not_hang_up_the_line(line: SimulatedLine) -> None:
    # Parity N: on some kernels (seen on 6.18) a pty takes PARENB once, drops it, and answers
    # EINVAL to every later request for it, so pyserial can't open the same pty twice with "E".
    for _ in range(3):
        with serial.Serial(line.path, 115200, timeout=1) as port:
            assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)


def test_stop_is_prompt_and_leaves_no_thread() -> None:
    line = SimulatedLine([1], baudrate=115200)
    line.start()
    time.sleep(0.05)  # the line serving a while, as it is when a test stops it
    started = time.monotonic()
    line.stop()
    assert time.monotonic() - started < 0.5
    assert not [t for t in threading.enumerate() if t.name == "simulated-line"]
    line.stop()  # twice is harmless


def test_unknown_address_in_a_control_call_is_refused(line: SimulatedLine) -> None:
    with pytest.raises(ValueError, match=r"no simulated drive at address 7"):
        line.inject_fault(7, 35)


# ---------------------------------------------------------------- invt-gateway simulate


def test_simulate_command_serves_answers_commands_and_exits_on_sigterm() -> None:
    command = [
        sys.executable,
        "-m",
        "gateway",
        "simulate",
        "--pty",
        "--address",
        "1",
        "--address",
        "3",
        "--no-wire-time",
        "--baud",
        "115200",
        "--fault-history",
        "3=35,35,35,35,35,35",
        "--dead",
        "3",
    ]
    process = subprocess.Popen(
        command,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert process.stdin is not None
    assert process.stdout is not None

    def command_answer(text: str) -> str:
        assert process.stdin is not None
        assert process.stdout is not None
        process.stdin.write(text + "\n")
        process.stdin.flush()
        return process.stdout.readline().strip()

    try:
        path = process.stdout.readline().strip()
        assert path.startswith("/dev/")
        with serial.Serial(path, 115200, parity="E", timeout=1) as port:
            assert exchange(port, bytes.fromhex(READ_STATE_WORD_1)) == bytes.fromhex(STOPPED_REPLY)
            port.write(bytes.fromhex("03 03 07 1B 00 06 B5 59"))
            assert silent(port)  # --dead 3
            assert command_answer("alive 3") == "ok alive 3"
            assert exchange(port, bytes.fromhex("03 03 07 1B 00 06 B5 59")) == bytes.fromhex(
                "03 03 0C 00 23 00 23 00 23 00 23 00 23 00 23 5F D2"
            )
            assert command_answer("fault 1 35") == "ok fault 1 35"
            assert exchange(port, frame(1, "03 21 02 00 01")) == frame(1, "03 02 00 23")
            answer = command_answer("stats")
            assert answer.startswith("ok ")
            stats = json.loads(answer[3:])
            assert stats["requests"] == 4
            assert stats["ignored"] == 1
            assert command_answer("fault 9 35").startswith("error ")
            assert command_answer("launch").startswith("error unknown command")
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=5) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        for stream in (process.stdin, process.stdout, process.stderr):
            if stream is not None:
                stream.close()


@pytest.mark.parametrize(
    ("arguments", "reason"),
    [
        (["--fault", "1:35"], "expected ADDR=CODE"),
        (["--wake-early-us", "-1"], "--wake-early-us: wake-early -1 us is outside 0..10000"),
    ],
)
def test_simulate_command_rejects_bad_arguments(arguments: list[str], reason: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "gateway", "simulate", "--pty", *arguments],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert result.returncode == 2
    assert reason in result.stderr


def test_control_commands_in_process(tmp_path: Path) -> None:
    link = tmp_path / "ttyINVT"
    with SimulatedLine([1, 2], baudrate=115200, wire_time=False, link=str(link)) as line:
        assert run_control_command(line, "dead 2") == "ok dead 2"
        assert run_control_command(line, "delay 1 250") == "ok delay 1 250"
        assert run_control_command(line, "fault 1 18") == "ok fault 1 18"
        assert run_control_command(line, "clear 1") == "ok clear 1"
        assert run_control_command(line, "noise 55AA") == "ok noise 2"
        assert run_control_command(line, "unplug") == "ok unplug"
        assert not link.exists()
        assert run_control_command(line, "replug") == f"ok replug {link}"
        assert link.is_symlink()
        assert run_control_command(line, "delay 1") == ("error delay takes 2 argument(s); " + USAGE)
        assert run_control_command(line, "fault one 35").startswith("error invalid literal")
        assert run_control_command(line, "noise XYZ").startswith("error non-hexadecimal")
        assert run_control_command(line, "").startswith("error empty command")
        with line.lock:
            assert line.drives[1].fault_code == 0


def _signal_thread(pid: int, tid: int, number: int) -> None:
    """Send `number` to one thread of another process (glibc's tgkill; Python has no wrapper)."""
    libc = process_libc()
    assert libc is not None
    if libc.tgkill(pid, tid, number) != 0:
        raise OSError(ctypes.get_errno(), "tgkill failed")


@contextlib.contextmanager
def simulate_started(link: Path) -> Iterator[subprocess.Popen[str]]:
    """`invt-gateway simulate --pty --link link`, once it has printed its port; killed if the
    test leaves it running."""
    process = subprocess.Popen(
        [sys.executable, "-m", "gateway", "simulate", "--pty", "--link", str(link)],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert process.stdout is not None
        assert process.stdout.readline().strip() == str(link)
        yield process
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        if process.stdout is not None:
            process.stdout.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="threads by /proc and tgkill")
def test_simulate_stops_on_a_signal_the_kernel_gave_to_the_line_thread(tmp_path: Path) -> None:
    """A process's signal may land on any of its threads. When it landed on the simulated
    line's thread, the main thread's select was never interrupted and `simulate` never exited."""
    link = tmp_path / "ttyINVT0"
    with simulate_started(link) as process:
        others = [int(t) for t in os.listdir(f"/proc/{process.pid}/task") if int(t) != process.pid]
        assert others, "the simulated line runs in a thread of its own"
        _signal_thread(process.pid, others[0], signal.SIGTERM)
        assert process.wait(timeout=5) == 0
        assert not link.exists()


def test_simulate_command_stops_cleanly_on_sigint_right_after_start(tmp_path: Path) -> None:
    link = tmp_path / "ttyINVT0"
    with simulate_started(link) as process:
        assert link.is_symlink()
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=5) == 0
        assert not link.exists()  # the link is removed on the way out
