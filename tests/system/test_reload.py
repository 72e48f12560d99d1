"""A live reload under load: a real `invt-gateway run` on two simulated lines, a SCADA client
reading every 20 ms, and SIGHUP with a new file that adds a drive, removes another and changes an
access rule; then SIGHUP with an invalid file. The client's one connection stays open
throughout."""

from __future__ import annotations

import asyncio
import contextlib
import copy
import signal
import urllib.error
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.profile.invt import STATE_WORD_1
from gateway.settings.reload import plan
from tests.support import TcpClient, free_port, read_pdu, read_state_word, write_pdu
from tests.support.http import Scrape, http_get
from tests.support.processes import GatewayProcess, gateway_process, run_cli

FREQUENCY_SETPOINT = 0x2001


def config(line1: str, line2: str, port: int, drives: list[dict[str, Any]], **tcp: Any) -> Any:
    bus = {"baudrate": 115200, "parity": "E", "timeout_ms": 200, "retries": 1}
    return {
        "gateway_id": "reload",
        "modbus_tcp": {"host": "127.0.0.1", "port": port, **tcp},
        "buses": [{"name": "line1", "port": line1, **bus}, {"name": "line2", "port": line2, **bus}],
        "drives": drives,
    }


BEFORE = [
    {"name": "pump1", "bus": "line1", "address": 1},
    {"name": "fan2", "bus": "line1", "address": 2},
    {"name": "conv3", "bus": "line2", "address": 1, "unit_id": 3},
]
AFTER = [
    {"name": "pump1", "bus": "line1", "address": 1},
    {"name": "conv3", "bus": "line2", "address": 1, "unit_id": 3},
    {"name": "mixer4", "bus": "line2", "address": 2, "unit_id": 4},
]
NO_SETPOINT_WRITES_TO_PUMP1 = [
    {"name": "pump1-read-only", "unit_ids": [1], "functions": [6], "allow": False}
]


class Load:
    """One connection reading the unaffected drives in turn, every 20 ms."""

    def __init__(self, client: TcpClient, unit_ids: tuple[int, ...]) -> None:
        self.client = client
        self.unit_ids = unit_ids
        self.ok = 0
        self.errors: list[str] = []
        self.lock = asyncio.Lock()  # the test's own requests share the connection
        self.progress = asyncio.Condition()

    async def run(self) -> None:
        while True:
            for unit_id in self.unit_ids:
                async with self.lock:
                    reply = await self.client.request(unit_id, read_pdu(STATE_WORD_1))
                if reply == bytes.fromhex("03 02 00 03"):
                    self.ok += 1
                else:
                    self.errors.append(f"unit {unit_id}: {reply.hex(' ')}")
                async with self.progress:
                    self.progress.notify_all()
                await asyncio.sleep(0.02)  # the client's own pace, not synchronisation

    async def more(self, count: int) -> None:
        """Until `count` more reads have been answered."""
        target = self.ok + count
        async with self.progress:
            await asyncio.wait_for(self.progress.wait_for(lambda: self.ok >= target), 10)

    async def request(self, unit_id: int, pdu: bytes) -> bytes:
        async with self.lock:
            return await self.client.request(unit_id, pdu)


@contextlib.asynccontextmanager
async def load_on(port: int, unit_ids: tuple[int, ...] = (1, 3)) -> AsyncIterator[Load]:
    client = await TcpClient.connect(port)
    load = Load(client, unit_ids)
    task = asyncio.create_task(load.run())
    try:
        yield load
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        await client.close()


def reload_with(gateway: GatewayProcess, content: str, expect: str) -> str:
    count = gateway.log.count(expect)
    gateway.config_file.write_text(content, encoding="utf-8")
    gateway.signal(signal.SIGHUP)
    gateway.log.wait_for_count(expect, count + 1)
    return [line for line in gateway.log.lines if expect in line][-1]


async def test_reload_under_load_adds_removes_and_changes_a_rule(tmp_path: Path) -> None:
    port = free_port()
    with (
        SimulatedLine(addresses=[1, 2], baudrate=115200, parity="E") as line1,
        SimulatedLine(addresses=[1, 2], baudrate=115200, parity="E") as line2,
        gateway_process(config(line1.path, line2.path, port, BEFORE), tmp_path) as gateway,
    ):
        await asyncio.to_thread(gateway.wait_ready)
        async with load_on(port) as load:
            await load.more(10)
            assert await load.request(2, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")
            assert (await load.request(1, write_pdu(FREQUENCY_SETPOINT, 1000)))[0] == 0x06
            assert (await load.request(4, read_pdu(STATE_WORD_1))) == bytes.fromhex("83 0A")

            new = config(line1.path, line2.path, port, AFTER, access=NO_SETPOINT_WRITES_TO_PUMP1)
            line = await asyncio.to_thread(
                reload_with, gateway, yaml.safe_dump(new), "config reloaded"
            )
            assert "drives added: mixer4" in line
            assert "drives removed: fan2" in line
            assert "modbus_tcp.access" in line
            assert "restart needed" not in line
            await load.more(10)
            assert await load.request(2, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0A")
            assert await load.request(4, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")
            # The new rule: set-point writes to pump1 refused (01H), other drives still written.
            refused = await load.request(1, write_pdu(FREQUENCY_SETPOINT, 1000))
            assert refused == bytes.fromhex("86 01")
            assert (await load.request(3, write_pdu(FREQUENCY_SETPOINT, 1000)))[0] == 0x06

            # An invalid file changes nothing: named key, and everything keeps running.
            broken = config(
                line1.path, line2.path, port, [*AFTER, {"name": "x", "bus": "line9", "address": 9}]
            )
            line = await asyncio.to_thread(
                reload_with, gateway, yaml.safe_dump(broken), "reload refused"
            )
            assert "drives[3] (x).bus" in line
            await load.more(10)
            assert await load.request(4, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")
            assert await load.request(2, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0A")

            # Keys that need a restart keep their running values, and say so.
            moved = config(line1.path, line2.path, free_port(), AFTER)
            line = await asyncio.to_thread(
                reload_with, gateway, yaml.safe_dump(moved), "config reloaded"
            )
            assert "restart needed for: modbus_tcp.port" in line
            assert "modbus_tcp.access" in line  # the rule, gone from the file, is lifted
            await load.more(10)
            assert (await load.request(1, write_pdu(FREQUENCY_SETPOINT, 1000)))[0] == 0x06
            assert not load.client.reader.at_eof()  # the one connection, open throughout
        assert load.errors == []
        assert gateway.process.poll() is None  # still running


async def test_a_bus_with_new_settings_is_reopened_alone_under_load(tmp_path: Path) -> None:
    port = free_port()
    with (
        SimulatedLine(addresses=[1, 2], baudrate=115200, parity="E") as line1,
        SimulatedLine(addresses=[1, 2], baudrate=115200, parity="E") as line2,
        gateway_process(config(line1.path, line2.path, port, AFTER), tmp_path) as gateway,
    ):
        await asyncio.to_thread(gateway.wait_ready)
        async with load_on(port, unit_ids=(1,)) as load:  # pump1, on line1
            await load.more(10)
            assert await load.request(3, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")
            slower = config(line1.path, line2.path, port, AFTER)
            slower["buses"][1]["baudrate"] = 57600  # the pty takes any baud rate
            line = await asyncio.to_thread(
                reload_with, gateway, yaml.safe_dump(slower), "config reloaded"
            )
            assert "buses reopened: line2" in line
            assert "restart needed" not in line
            gateway.log.wait_for_count("bus line2: reopened with new settings", 1)
            await load.more(10)
            # line2's drives answer on the reopened bus, a write too.
            assert await load.request(3, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")
            assert await load.request(4, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")
            assert (await load.request(4, write_pdu(FREQUENCY_SETPOINT, 1000)))[0] == 0x06
            await load.more(10)
            assert not load.client.reader.at_eof()  # the one connection, open throughout
        assert load.errors == []  # line1 was never interrupted
        assert gateway.log.count(f"bus line1: {line1.path} open") == 1  # its port kept
        assert gateway.log.count(f"bus line2: {line2.path} open") == 2
        assert gateway.process.poll() is None


async def test_metrics_move_to_a_new_port_and_name_an_added_drive(tmp_path: Path) -> None:
    port, before_port, after_port = free_port(), free_port(), free_port()
    with (
        SimulatedLine(addresses=[1, 2], baudrate=115200, parity="E") as line1,
        SimulatedLine(addresses=[1, 2], baudrate=115200, parity="E") as line2,
    ):
        first = config(line1.path, line2.path, port, BEFORE)
        first["metrics"] = {"enabled": True, "port": before_port}
        with gateway_process(first, tmp_path) as gateway:
            await asyncio.to_thread(gateway.wait_ready)
            assert (await http_get(before_port, "/metrics"))[0] == 200
            moved = config(line1.path, line2.path, port, AFTER)
            moved["metrics"] = {"enabled": True, "port": after_port}
            line = await asyncio.to_thread(
                reload_with, gateway, yaml.safe_dump(moved), "config reloaded"
            )
            assert "metrics.host/port" in line
            assert "drives added: mixer4" in line
            assert "restart needed" not in line
            client = await TcpClient.connect(port)
            assert await client.request(4, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")
            await client.close()
            status, _, text = await http_get(after_port, "/metrics")
            assert status == 200
            scrape = Scrape(text)
            tcp_reads = scrape(
                "requests_total", bus="line2", drive="mixer4", source="tcp", function="03"
            )
            assert tcp_reads == 1
            assert scrape("drive_online", bus="line2", drive="mixer4") == 1
            assert "address_2" not in text
            with pytest.raises(urllib.error.URLError, match="refused"):  # the old one let go
                await http_get(before_port, "/metrics")


def test_what_a_reload_applies_and_what_waits_for_a_restart() -> None:
    old = GatewayConfig.model_validate(config("/dev/ttyA", "/dev/ttyB", 5020, BEFORE))
    changed_bus = config("/dev/ttyA", "/dev/ttyB", 5020, AFTER)
    changed_bus["buses"][1]["baudrate"] = 9600
    changed_bus["gateway_id"] = "renamed"
    changed_bus["storage"] = {"path": "/elsewhere/events.db", "max_mb": 10}
    changed_bus["console"] = {"enabled": False, "port": 8099}
    changed_bus["metrics"] = {"enabled": False, "port": 9999}  # off: nothing to move
    changed_bus["opcua"] = {"port": 4841, "anonymous": True}
    result = plan(old, GatewayConfig.model_validate(changed_bus), mqtt_running=False)
    assert result.restart_needed == [
        "gateway_id",
        "storage.path",
        "console.port",
        "opcua.port",
        "opcua.anonymous",
    ]
    assert result.changed == [
        "storage",
        "buses reopened: line2",
        "drives added: mixer4",
        "drives removed: fan2",
    ]
    assert result.reopened == ["line2"]
    running = result.running
    assert running.gateway_id == "reload"  # the running values stay
    assert running.storage.path is None
    assert running.storage.max_mb == 10
    assert running.console.port == 8080
    assert (running.opcua.port, running.opcua.anonymous) == (4840, False)
    assert [b.baudrate for b in running.buses] == [115200, 9600]
    assert [d.name for d in running.drives] == ["pump1", "conv3", "mixer4"]
    assert [d.name for d in result.added] == ["mixer4"]
    assert result.removed == ["fan2"]


def test_buses_added_or_removed_wait_for_a_restart_with_their_drives() -> None:
    old = GatewayConfig.model_validate(config("/dev/ttyA", "/dev/ttyB", 5020, BEFORE))
    new = copy.deepcopy(config("/dev/ttyA", "/dev/ttyB", 5020, BEFORE))  # BEFORE stays as it is
    new["buses"][1]["name"] = "line3"
    new["drives"][2]["bus"] = "line3"
    result = plan(old, GatewayConfig.model_validate(new), mqtt_running=False)
    assert result.restart_needed == [
        "bus line3 (added)",
        "bus line2 (removed)",
        "drive conv3 (its bus is added or removed)",
    ]
    assert [b.name for b in result.running.buses] == ["line1", "line2"]
    assert result.running.drives == old.drives


def test_mqtt_settings_apply_and_turning_mqtt_on_waits_for_a_restart() -> None:
    old = GatewayConfig.model_validate(
        {**config("/dev/ttyA", "/dev/ttyB", 5020, BEFORE), "mqtt": {"host": "127.0.0.1"}}
    )
    moved = {**config("/dev/ttyA", "/dev/ttyB", 5020, BEFORE), "mqtt": {"host": "10.0.0.9"}}
    result = plan(old, GatewayConfig.model_validate(moved), mqtt_running=True)
    assert result.changed == ["mqtt"]
    assert result.restart_bridge
    assert result.running.mqtt is not None
    assert result.running.mqtt.host == "10.0.0.9"
    off = {**moved, "mqtt": {"host": "10.0.0.9", "enabled": False}}
    result = plan(old, GatewayConfig.model_validate(off), mqtt_running=True)
    assert result.restart_needed == ["mqtt.enabled"]
    assert not result.restart_bridge
    assert result.running.mqtt == old.mqtt


def test_the_reload_command_says_applied_or_refused_with_the_key(tmp_path: Path) -> None:
    """`invt-gateway reload` (the unit's ExecReload): exit 0 only when the file was applied; a
    refused file exits 3 with each problem's key, and the gateway keeps what it ran."""
    port = free_port()
    with (
        SimulatedLine(addresses=[1, 2], baudrate=115200, parity="E") as line1,
        SimulatedLine(addresses=[1, 2], baudrate=115200, parity="E") as line2,
        gateway_process(config(line1.path, line2.path, port, BEFORE), tmp_path) as gateway,
    ):
        gateway.wait_ready()
        path = str(gateway.config_file)
        assert read_state_word(port, 4) == bytes.fromhex("83 0A")  # mixer4: not there yet

        gateway.config_file.write_text(yaml.safe_dump(config(line1.path, line2.path, port, AFTER)))
        applied = run_cli("reload", "--config", path)
        assert applied.returncode == 0, applied.stderr
        assert applied.stdout.startswith("applied: ")
        assert "drives added: mixer4" in applied.stdout
        assert read_state_word(port, 4) == bytes.fromhex("03 02 00 03")

        gateway.config_file.write_text("buses: [unclosed\n")
        broken = run_cli("reload", "--config", path)
        assert broken.returncode == 3
        assert broken.stderr.startswith(f"refused: {path}: ")

        invalid = config(line1.path, line2.path, port, BEFORE)
        invalid["modbus_tcp"]["idle_timeout_s"] = -1
        invalid["drives"].append({"name": "x", "bus": "line9", "address": 9})
        gateway.config_file.write_text(yaml.safe_dump(invalid))
        refused = run_cli("reload", "--config", path)
        assert refused.returncode == 3
        assert refused.stdout == ""
        assert "modbus_tcp.idle_timeout_s" in refused.stderr
        # The running configuration stays: mixer4 (added before) answers, fan2 stays removed.
        assert read_state_word(port, 4) == bytes.fromhex("03 02 00 03")
        assert read_state_word(port, 2) == bytes.fromhex("83 0A")
        assert gateway.log.count("reload refused") >= 2  # the journal says it too
        assert gateway.process.poll() is None

    gone = run_cli("reload", "--config", path)  # the gateway has stopped
    assert gone.returncode == 1
    assert "no gateway runs with" in gone.stderr
