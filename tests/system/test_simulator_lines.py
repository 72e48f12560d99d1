"""Several simulated lines in one process (`simulate --lines N`, `LineServer`): each line on its
own pty answers as a line of its own would, with its own wire timing, t3.5 check and drives,
while one thread serves them all."""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import threading
import time

import serial
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusIOException

from gateway.instruments.simulator import SimulatedLine
from gateway.instruments.simulator.server import LineServer
from gateway.modbus.rtu import build_frame
from tests.support.serial_master import exchange, read_reply

BAUD = 115200
CHARACTER_S = 11 / BAUD  # 8E1
T35_S = 0.00175  # above 19200 baud the spec fixes t3.5
RESPONSE_DELAY_S = 0.005
LINES = 3
SET_POINT = 0x2001  # frequency set-point, written to RAM


def request(address: int, pdu_hex: str) -> bytes:
    return build_frame(address, bytes.fromhex(pdu_hex))


class Simulator:
    """`invt-gateway simulate --lines N` as a user starts it, with its control commands."""

    def __init__(self, *arguments: str) -> None:
        command = [sys.executable, "-m", "gateway", "simulate", "--pty", *arguments]
        self.process = subprocess.Popen(
            command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )

    def paths(self, count: int) -> list[str]:
        assert self.process.stdout is not None
        return [self.process.stdout.readline().strip() for _ in range(count)]

    def command(self, text: str) -> str:
        assert self.process.stdin is not None
        assert self.process.stdout is not None
        self.process.stdin.write(text + "\n")
        self.process.stdin.flush()
        return self.process.stdout.readline().strip()

    def stats(self, line: int) -> dict[str, int]:
        answer = self.command(f"line {line} stats")
        assert answer.startswith("ok "), answer
        stats: dict[str, int] = json.loads(answer[3:])
        return stats

    def stop(self) -> int:
        self.process.terminate()
        code = self.process.wait(timeout=5)
        for stream in (self.process.stdin, self.process.stdout):
            if stream is not None:
                stream.close()
        return code


def test_each_line_has_its_own_pty_and_its_own_drives() -> None:
    # No parity: pymodbus changes a port's settings after opening it, which some kernels
    # refuse on a pty once parity was asked for.
    arguments = ["--lines", str(LINES), "--address", "1", "--address", "2", "--parity", "N"]
    simulator = Simulator(*arguments)
    try:
        paths = simulator.paths(LINES)
        assert len(set(paths)) == LINES
        assert all(p.startswith("/dev/") for p in paths)
        # pymodbus's serial client, a master nobody here wrote, on each line: a write of its
        # own to each line's drive 1, then every line read back.
        with contextlib.ExitStack() as stack:
            clients = [
                stack.enter_context(
                    ModbusSerialClient(path, baudrate=BAUD, parity="N", timeout=0.3, retries=0)
                )
                for path in paths
            ]
            assert all(client.connected for client in clients)
            for number, client in enumerate(clients, 1):
                assert not client.write_register(SET_POINT, 1000 * number, device_id=1).isError()
            for number, client in enumerate(clients, 1):
                read = client.read_holding_registers(SET_POINT, count=1, device_id=1)
                assert read.registers == [1000 * number]
            # A control command reaches the line it names, and only that one.
            assert simulator.command("line 2 dead 1") == "ok dead 1"
            answered = []
            for client in clients:
                try:
                    reply = client.read_holding_registers(0x2100, device_id=1)
                    answered.append(not reply.isError())
                except ModbusIOException:  # no reply at all
                    answered.append(False)
            assert answered == [True, False, True]
        assert [simulator.stats(n)["ignored"] for n in (1, 2, 3)] == [0, 1, 0]
        assert simulator.command("line 4 stats") == f"error no line 4: there are {LINES}"
        assert simulator.command("stats").startswith("ok {")  # no `line K`: the first line
        assert simulator.stop() == 0
    finally:
        if simulator.process.poll() is None:
            simulator.process.kill()
            simulator.process.wait()


def test_lines_in_one_process_keep_their_own_wire_time_and_gap() -> None:
    """All lines busy at once: each transaction takes its own wire time and response delay,
    not the others' (one thread serves them, but no line waits for another's reply); a master
    that breaks t3.5 on one line is counted on that line only."""
    simulator = Simulator("--lines", str(LINES), "--address", "1", "--baud", str(BAUD))
    try:
        ports = [serial.Serial(path, BAUD, parity="E", timeout=1) for path in simulator.paths(3)]
        state = request(1, "03 21 00 00 01")  # 8 bytes; the reply is 7
        least_s = (8 + 7) * CHARACTER_S + RESPONSE_DELAY_S
        durations: dict[int, list[float]] = {n: [] for n in range(LINES)}

        def master(number: int) -> None:
            for _ in range(20):
                started = time.monotonic()
                assert exchange(ports[number], state) == request(1, "03 02 00 03")
                durations[number].append(time.monotonic() - started)
                time.sleep(2 * T35_S)  # the gap a master keeps

        started = time.monotonic()
        masters = [threading.Thread(target=master, args=(n,)) for n in range(LINES)]
        for thread in masters:
            thread.start()
        for thread in masters:
            thread.join()
        elapsed = time.monotonic() - started
        for each in durations.values():
            assert min(each) >= least_s  # never early: the wire and the drive's delay kept
        # Twenty transactions on each of three lines, side by side: the time of twenty on
        # one line (about 0.2 s), far from the sixty one after another would take.
        assert elapsed < 20 * (least_s + 2 * T35_S) * 2
        assert [simulator.stats(n)["replies"] for n in (1, 2, 3)] == [20, 20, 20]
        # Line 2's master writes two requests at once: the second starts before the first
        # has left the wire, a t3.5 violation on that line only.
        ports[1].write(state * 2)
        read_reply(ports[1], len(state))
        read_reply(ports[1], len(state))
        violations = [simulator.stats(n)["gap_violations"] for n in (1, 2, 3)]
        assert violations == [0, 1, 0]
        for port in ports:
            port.close()
    finally:
        simulator.stop()


def test_simulate_lines_refuses_a_link_and_out_of_range_counts() -> None:
    def run(*arguments: str) -> subprocess.CompletedProcess[str]:
        command = [sys.executable, "-m", "gateway", "simulate", "--pty", *arguments]
        return subprocess.run(command, capture_output=True, text=True, timeout=30, check=False)

    linked = run("--lines", "2", "--link", "/tmp/never-made")
    assert linked.returncode == 2
    assert "--lines takes --pty and no --link" in linked.stderr
    for count in ("0", "65"):
        refused = run("--lines", count)
        assert refused.returncode == 2
        assert f"--lines: {count} lines is outside 1..64" in refused.stderr


def test_a_line_server_serves_lines_from_one_thread_and_stops_them_together() -> None:
    lines = [SimulatedLine([1], baudrate=BAUD, wire_time=False) for _ in range(4)]
    server = LineServer(lines)
    server.start()
    try:
        assert [t.name for t in threading.enumerate()].count("simulated-lines") == 1
        ports = [serial.Serial(line.path, BAUD, parity="E", timeout=1) for line in lines]
        for number, (line, port) in enumerate(zip(lines, ports, strict=True)):
            line.write_raw(b"")  # a control call, carried out on the serving thread
            write = request(1, f"06 20 01 {number:04X}")
            assert exchange(port, write) == write  # a write's reply echoes it
        for number, port in enumerate(ports):
            assert exchange(port, request(1, "03 20 01 00 01")) == request(1, f"03 02 {number:04X}")
            port.close()
    finally:
        lines[2].stop()  # one line's stop stops the thread, and so every line
    assert not [t for t in threading.enumerate() if t.name == "simulated-lines"]
    server.stop()  # twice is harmless
