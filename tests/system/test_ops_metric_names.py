"""Every metric the gateway publishes keeps its name, type, labels and help text: dashboards and
alerts are built on them (a public name: add, never rename). A real gateway with every part on
(MQTT to a real Mosquitto, the console, the store, an access rule, the ProcessCollector), real
traffic on a pty line so that every family has samples to show its labels, scraped over HTTP and
held against the list in `tests/fixtures/metric_families.tsv`.

A family added on purpose goes into the list with it (`python -m tests.system.test_ops_metric_names
FILE` prints the lines a scrape file has, in the list's form).
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path
from typing import Any

from prometheus_client.parser import text_string_to_metric_families

from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, free_port, present, read_pdu, running_gateway, write_pdu
from tests.support.http import http_get
from tests.support.mosquitto import Mosquitto, unique_base_topic

PINNED = Path(__file__).parents[1] / "fixtures" / "metric_families.tsv"
STATE_WORD_1 = 0x2100


def families(text: str) -> dict[str, str]:
    """Family name → "type<TAB>labels<TAB>help", the labels those its samples carry."""
    found = {}
    for family in text_string_to_metric_families(text):
        labels = sorted({name for s in family.samples for name in s.labels} - {"le"})
        found[family.name] = f"{family.type}\t{','.join(labels)}\t{family.documentation}"
    return found


def pinned() -> dict[str, str]:
    lines = PINNED.read_text(encoding="utf-8").splitlines()
    return dict(line.split("\t", 1) for line in lines if line and not line.startswith("#"))


def everything_on(line: SimulatedLine, broker: Mosquitto, tmp_path: Path) -> GatewayConfig:
    config: dict[str, Any] = {
        "gateway_id": "names",
        "modbus_tcp": {
            "host": "127.0.0.1",
            "port": 0,
            # No multiple writes to the fan: a rule to count refusals under.
            "access": [{"name": "fan", "unit_ids": [2], "functions": [0x10], "allow": False}],
        },
        "buses": [
            {
                "name": "line1",
                "port": line.path,
                "baudrate": 115200,
                "timeout_ms": 100,
                "retries": 1,
                "offline_after": 1,
            }
        ],
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1, "model": "gd350"},
            {"name": "fan2", "bus": "line1", "address": 2, "model": "gd20"},
            {"name": "ghost", "bus": "line1", "address": 9, "model": "gd20"},
        ],
        "mqtt": {"host": broker.host, "port": broker.port, "base_topic": unique_base_topic()},
        "metrics": {"enabled": True, "host": "127.0.0.1", "port": free_port()},
        "console": {"enabled": True, "port": 0, "anonymous_view": True},
        "storage": {"path": str(tmp_path / "events.db")},
    }
    return GatewayConfig.model_validate(config)


async def test_every_published_metric_keeps_its_name_type_labels_and_help(
    line: SimulatedLine, mosquitto: Mosquitto, tmp_path: Path
) -> None:
    config = everything_on(line, mosquitto, tmp_path)
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.read(1, STATE_WORD_1) == [3]
        assert await client.request(9, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0b")
        write_two = struct.pack(">BHHBHH", 0x10, 0x0001, 2, 4, 0, 0)
        assert await client.request(2, write_two) == bytes.fromhex("90 01")
        # P00.01 = 3 is out of range: the drive's own exception 04H.
        assert await client.request(2, write_pdu(0x0001, 3)) == bytes.fromhex("86 04")
        line.set_line_faults(rate=1.0, kinds=["crc"])  # a reply spoilt: a bad reply, by kind
        assert await client.request(2, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0b")
        line.set_line_faults(rate=0.0)
        assert await client.request(0, write_pdu(0x2000, 5)) == write_pdu(0x2000, 5)
        await present(app.mqtt).connected.wait()
        assert config.metrics.port is not None
        status, _, text = await http_get(config.metrics.port, "/metrics")
        await client.close()
    assert status == 200
    published = families(text)
    missing = sorted(name for name in pinned() if name not in published)
    assert missing == [], f"families gone from /metrics: {missing}"
    changed = {
        name: (was, published[name]) for name, was in pinned().items() if published[name] != was
    }
    assert changed == {}, "type, labels or help changed (was, now)"


if __name__ == "__main__":
    for name, line in sorted(families(Path(sys.argv[1]).read_text(encoding="utf-8")).items()):
        print(f"{name}\t{line}")
