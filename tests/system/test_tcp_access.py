"""Access control (`modbus_tcp.access`): who may do what, refused with 01H or 02H and counted.

End to end over real sockets to simulated drives (a refused write must leave the drive as it
was), then the rule semantics as pure functions, then the configuration's checks.
"""

from __future__ import annotations

import asyncio
import logging
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from gateway.config import GatewayConfig, parse_config
from gateway.errors import ConfigError
from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, free_port, running_gateway, write_many, write_pdu
from tests.support.processes import run_cli

pytestmark = pytest.mark.line(addresses=[1, 2, 3])

SCADA_RULES: list[dict[str, Any]] = [
    {
        "name": "scada-commands",
        "unit_ids": [1, 2],
        "functions": [6, "10H"],
        "registers": ["2000H-2001H"],
        "allow": True,
    },
    {
        "name": "no-parameter-writes",
        "unit_ids": [1, 2],
        "functions": [6, 16, 22, 23],
        "registers": ["P00.00-P99.99"],
        "allow": False,
    },
    {"name": "watch-only", "unit_ids": [3], "functions": [5, 6, 15, 16, 22, 23], "allow": False},
]
P00_11 = 0x000B
FREQUENCY_SETPOINT = 0x2001


def config_with_rules(
    line_path: str, rules: list[dict[str, Any]], metrics_port: int | None = None
) -> GatewayConfig:
    metrics = {"enabled": metrics_port is not None, "host": "127.0.0.1", "port": metrics_port or 1}
    return GatewayConfig.model_validate(
        {
            "metrics": metrics,
            "modbus_tcp": {"host": "127.0.0.1", "port": 0, "access": rules},
            "buses": [{"name": "line1", "port": line_path, "baudrate": 115200}],
            "drives": [
                {"name": "pump1", "bus": "line1", "address": 1},
                {"name": "fan2", "bus": "line1", "address": 2},
                {"name": "conveyor", "bus": "line1", "address": 3},
            ],
        }
    )


def scrape(port: int) -> dict[str, float]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=5) as response:
        text = response.read().decode()
    values = {}
    for line in text.splitlines():
        if line and not line.startswith("#"):
            name, _, value = line.rpartition(" ")
            values[name] = float(value)
    return values


async def test_scada_may_write_commands_but_no_parameters(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG, logger="gateway.tcp.server")
    metrics_port = free_port()
    async with running_gateway(config_with_rules(line.path, SCADA_RULES, metrics_port)) as app:
        client = await TcpClient.connect(app.tcp.port)
        try:
            # Allowed: the set-point and run/stop, by 06H and 10H; reads of anything.
            assert await client.request(1, write_pdu(FREQUENCY_SETPOINT, 2500)) == write_pdu(
                FREQUENCY_SETPOINT, 2500
            )
            assert await client.request(1, write_many(0x2000, 5, 3000)) == bytes.fromhex(
                "10 20 00 00 02"
            )
            assert await client.read(1, P00_11) == [100]
            assert await client.read(3, 0x2100) == [3]
            # Refused, 02H: a parameter, its RAM-only twin, and a 10H that reaches one
            # forbidden register (2002H is inside P00.00-P99.99) refused whole.
            assert await client.request(1, write_pdu(P00_11, 50)) == bytes.fromhex("86 02")
            assert await client.request(2, write_pdu(0x8000 | P00_11, 50)) == bytes.fromhex("86 02")
            assert await client.request(1, write_many(0x2001, 1000, 7)) == bytes.fromhex("90 02")
            # Refused, 01H: no writes at all to the conveyor; a broadcast reaches it too.
            assert await client.request(3, write_pdu(0x2000, 1)) == bytes.fromhex("86 01")
            assert await client.request(0, write_pdu(0x2001, 1000)) == bytes.fromhex("86 01")
            # The allowed 10H set 3000; the refused 10H (1000, 7) and the broadcast changed nothing.
            assert await client.read(1, FREQUENCY_SETPOINT) == [3000]
        finally:
            await client.close()
        with line.lock:
            assert line.drives[1].parameter("P00.11") == 100
            assert line.drives[2].parameter("P00.11") == 100
            assert line.drives[3].state(time.monotonic()).name == "STOPPED"
        assert app.tcp.stats.denied == 5
        assert app.tcp.access is not None
        assert app.tcp.access.denied == [0, 3, 2]
        metrics = await asyncio.to_thread(scrape, metrics_port)
        assert metrics["invt_gateway_tcp_denied_total"] == 5
        by_rule = 'invt_gateway_tcp_denied_by_rule_total{rule="%s"}'
        assert metrics[by_rule % "scada-commands"] == 0
        assert metrics[by_rule % "no-parameter-writes"] == 3
        assert metrics[by_rule % "watch-only"] == 2
    assert "refused by modbus_tcp.access rule no-parameter-writes (exception 02H)" in caplog.text


async def test_without_rules_nothing_is_checked(line: SimulatedLine) -> None:
    async with running_gateway(config_with_rules(line.path, [])) as app:
        assert app.tcp.access is None  # the hot path tests one attribute, nothing more
        client = await TcpClient.connect(app.tcp.port)
        try:
            assert await client.request(1, write_pdu(P00_11, 50)) == write_pdu(P00_11, 50)
        finally:
            await client.close()


# -- the configuration -------------------------------------------------------------------------

BASE = """
buses: [{name: line1, port: /dev/ttyUSB0}]
drives: [{name: pump1, bus: line1, address: 1}, {name: fan2, bus: line1, address: 2}]
modbus_tcp:
  access:
"""


def problems(rules: str) -> list[str]:
    with pytest.raises(ConfigError) as raised:
        parse_config(BASE + rules)
    return [f"{path}: {reason}" if path else reason for path, reason in raised.value.problems]


def test_rules_spelled_as_people_write_them() -> None:
    config = parse_config(
        BASE
        + """
    - {name: setpoints, unit_ids: [1], functions: [6, 10H, 0x17], registers: [2000H-2001H, 8192,
       P00.00-P00.15, 0x3000], allow: true}
    - {allow: false}
"""
    )
    first, catch_all = config.modbus_tcp.access
    assert first.functions == (6, 16, 23)
    assert first.registers is not None
    assert [r.spans for r in first.registers] == [
        ((0x2000, 0x2001),),
        ((0x2000, 0x2000),),
        ((0x0000, 0x000F), (0x8000, 0x800F)),  # parameters: the RAM-only twins too
        ((0x3000, 0x3000),),
    ]
    assert catch_all.unit_ids is None
    assert catch_all.functions is None
    assert catch_all.registers is None


@pytest.mark.parametrize(
    ("rules", "expected"),
    [
        (
            "    - {unit_ids: [1, 9], allow: false}",
            "modbus_tcp.access[0].unit_ids: no drive has unit id 9 (drives: 1, 2; 0 is broadcast)",
        ),
        (
            "    - {name: w, registers: [2001H-2000H], allow: false}",
            "modbus_tcp.access[0] (w).registers[0]: '2001H-2000H': the first register comes after",
        ),
        (
            "    - {registers: [P00.100], allow: false}",
            "modbus_tcp.access[0].registers[0]: 'P00.100': 'P00.100' is not a register",
        ),
        ("    - {functions: [], allow: false}", "modbus_tcp.access[0].functions: an empty list"),
        ("    - {functions: [128], allow: false}", "modbus_tcp.access[0].functions[0]: "),
        ("    - {unit_ids: [1]}", "modbus_tcp.access[0].allow: required key is missing"),
        ("    - {allow: false, units: [1]}", "modbus_tcp.access[0].units: unknown key"),
    ],
)
def test_a_bad_rule_names_its_key_and_the_reason(rules: str, expected: str) -> None:
    found = problems(rules)
    assert any(p.startswith(expected) for p in found), found


def test_check_config_shows_the_rules_as_read(tmp_path: Path) -> None:
    path = tmp_path / "config.yaml"
    path.write_text(
        BASE + "    - {name: commands, functions: [6], registers: [P00.10-P00.12], allow: true}\n"
        "    - {unit_ids: [2], allow: false}\n"
    )
    result = run_cli("check-config", "--config", str(path))
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[-3:] == [
        "Modbus-TCP access (first matching rule decides; no match: allowed):",
        "  1. allow  any unit id, functions 06H, registers 000AH-000CH, 800AH-800CH  (commands)",
        "  2. refuse unit ids 2, any function  (access[1])",
    ]
