"""Property-based test of the Modbus-TCP framing against a running gateway, over real sockets.

Each example is a stream of MBAP frames (random unit ids, function codes and PDUs), mutated (bytes
flipped, inserted, deleted, cut short) and sent in random pieces on a fresh connection. An oracle
written here, independent of the gateway's parser, says which frames the gateway must find in
it: those before the first malformed header. The gateway must answer exactly those (all of them,
unless a malformed header closed the connection), each with its own transaction id, unit id and
function code, and never anything else. Meanwhile a second client reads drive 1 without pause
and must get every answer right: one client's garbage never leaks into another's stream.
"""

from __future__ import annotations

import itertools
import socket
import struct
import threading
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from gateway.instruments.simulator import SimulatedLine
from tests.support import RecordProperty, free_port, read_pdu, receive_exactly
from tests.support.processes import GatewayProcess, gateway_process

STATE_WORD_1 = 0x2100
STOPPED = 3
DRIVE_FOR_GARBAGE = 2
"""The only real drive the random frames may reach; the checker reads drive 1."""
UNKNOWN_UNIT = 77
EXAMPLES = 100


@dataclass(frozen=True)
class Frame:
    transaction_id: int
    unit_id: int
    function: int


def oracle(stream: bytes) -> tuple[list[Frame], bool]:
    """The complete frames a Modbus-TCP server must take from `stream`, and whether it must
    close the connection (a header with protocol id ≠ 0, or length outside 2..254)."""
    frames: list[Frame] = []
    position = 0
    while len(stream) - position >= 7:
        tid, protocol, length, unit = struct.unpack_from(">HHHB", stream, position)
        if protocol != 0 or not 2 <= length <= 254:
            return frames, True
        end = position + 6 + length
        if end > len(stream):
            break
        # A reply carries the request's function code, with the exception bit or without.
        frames.append(Frame(tid, unit, stream[position + 7] & 0x7F))
        position = end
    return frames, False


@st.composite
def frame_bytes(draw: st.DrawFn) -> bytes:
    unit = draw(st.sampled_from([DRIVE_FOR_GARBAGE, UNKNOWN_UNIT, 255]))
    pdu = draw(
        st.one_of(
            st.builds(read_pdu, st.integers(0x2100, 0x2103), st.integers(1, 3)),
            st.binary(min_size=1, max_size=40),
        )
    )
    tid = draw(st.integers(0, 0xFFFF))
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


@st.composite
def hostile_streams(draw: st.DrawFn) -> bytes:
    stream = bytearray(b"".join(draw(st.lists(frame_bytes(), min_size=1, max_size=8))))
    for _ in range(draw(st.integers(0, 3))):
        kind = draw(st.sampled_from(["flip", "insert", "delete", "cut"]))
        position = draw(st.integers(0, max(len(stream) - 1, 0)))
        if kind == "flip" and stream:
            stream[position] ^= 1 << draw(st.integers(0, 7))
        elif kind == "insert":
            stream[position:position] = draw(st.binary(min_size=1, max_size=6))
        elif kind == "delete" and stream:
            del stream[position : position + draw(st.integers(1, 4))]
        elif kind == "cut":
            del stream[position:]
    return bytes(stream)


@dataclass
class Checker:
    """A well-behaved client reading drive 1 in a loop; every answer must be right."""

    port: int
    reads: int = 0
    timeouts: int = 0
    """0BH answers: a loaded test machine may be slower than the response timeout; no harm."""
    problems: list[str] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)

    def run(self) -> None:
        with socket.create_connection(("127.0.0.1", self.port), timeout=5) as sock:
            tid = 0
            while not self._stop.is_set():
                tid = (tid + 1) & 0xFFFF
                pdu = read_pdu(STATE_WORD_1)
                sock.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, 1) + pdu)
                header = receive_exactly(sock, 7)
                got_tid, protocol, length, unit = struct.unpack(">HHHB", header)
                reply = receive_exactly(sock, length - 1)
                if (got_tid, protocol, unit) != (tid, 0, 1):
                    self.problems.append(f"tid {tid}: got the answer {header.hex()} {reply.hex()}")
                elif reply == bytes.fromhex("83 0B"):
                    self.timeouts += 1
                elif reply != bytes.fromhex("03 02 00 03"):
                    self.problems.append(f"tid {tid}: got the value {reply.hex()}")
                self.reads += 1

    def stop(self) -> None:
        self._stop.set()


@pytest.fixture(scope="module")
def gateway(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[int, GatewayProcess]]:
    directory: Path = tmp_path_factory.mktemp("tcp-properties")
    port = free_port()
    with SimulatedLine(addresses=[1, DRIVE_FOR_GARBAGE], baudrate=115200, wire_time=False) as line:
        config = {
            "gateway_id": "properties",
            "modbus_tcp": {"host": "127.0.0.1", "port": port, "max_requests_per_connection": 8},
            "buses": [
                {
                    "name": "line1",
                    "port": line.path,
                    "baudrate": 115200,
                    "timeout_ms": 200,
                    "retries": 1,
                    "offline_after": 1000,
                }
            ],
            "drives": [
                {"name": "pump1", "bus": "line1", "address": 1},
                {"name": "fan2", "bus": "line1", "address": DRIVE_FOR_GARBAGE},
            ],
        }
        with gateway_process(config, directory) as process:
            process.wait_ready()
            yield port, process


@pytest.fixture(scope="module")
def checker(gateway: tuple[int, GatewayProcess]) -> Iterator[Checker]:
    checker = Checker(gateway[0])
    thread = threading.Thread(target=checker.run, name="checker", daemon=True)
    thread.start()
    yield checker
    checker.stop()
    thread.join(5)


@settings(
    max_examples=EXAMPLES,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(stream=hostile_streams(), cuts=st.lists(st.integers(1, 400), max_size=4))
def test_hostile_streams_get_only_their_own_answers_and_nobody_else_notices(
    gateway: tuple[int, GatewayProcess], checker: Checker, stream: bytes, cuts: list[int]
) -> None:
    expected, must_close = oracle(stream)
    # Unit ids 0 (broadcast: drive 1 too) and 1 (the checker's drive) are left alone.
    assume(all(frame.unit_id not in (0, 1) for frame in expected))
    port, process = gateway
    due = Counter(expected)
    answered: list[Frame] = []
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        edges = sorted({0, *(c for c in cuts if c < len(stream)), len(stream)})
        closed = False
        for start, end in itertools.pairwise(edges):
            try:
                sock.sendall(stream[start:end])
            except ConnectionError:
                # The gateway closed on a malformed header while the rest was still being sent
                # (that is the point); any other close is the test's failure below.
                assert must_close, "the connection closed on a well-formed stream"
                closed = True
                break
            time.sleep(0.001)  # separate segments, most of the time
        deadline = time.monotonic() + 10
        while not closed and (must_close or len(answered) < len(expected)):
            if time.monotonic() > deadline:
                break
            try:
                header = receive_exactly(sock, 7)
                tid, protocol, length, unit = struct.unpack(">HHHB", header)
                pdu = receive_exactly(sock, length - 1)
            except ConnectionError:
                closed = True
                break
            assert protocol == 0
            assert 2 <= length <= 254
            frame = Frame(tid, unit, pdu[0] & 0x7F)
            assert due[frame] > 0, f"an answer nobody asked for: {frame} (expected {expected})"
            due[frame] -= 1
            answered.append(frame)
    if must_close:
        assert closed, "a malformed header must close the connection"
    else:
        assert len(answered) == len(expected), f"answered {answered}, expected {expected}"
    assert process.process.poll() is None
    assert checker.problems == []


def test_the_checker_kept_reading(checker: Checker, record_property: RecordProperty) -> None:
    """Runs after the property test (same module): the other client was served throughout."""
    assert checker.reads > 0
    assert checker.problems == []
    record_property(
        "figure:hostile MBAP streams",
        f"{EXAMPLES} random and mutated streams, each answered exactly; another client's "
        f"{checker.reads} reads meanwhile all right",
    )
