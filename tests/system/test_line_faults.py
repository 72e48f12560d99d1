"""Line faults: with 5 % of the drives' replies spoilt (bad CRC, truncated, extra bytes, from the
wrong address, late, missing), every value a client receives is the drive's true value, and the
retries keep the errors the clients see below 0.1 %.

The clients (`gateway.instruments.stress.checked_load`) write and read back parameter blocks
only they write, so they know every true value and check every answer; at the end the drives
themselves are compared with what the clients last wrote. A modest run here; `invt-gateway
stress` runs the same for as long as asked.
"""

from __future__ import annotations

import asyncio
import time

from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.instruments.simulator.line_faults import KINDS
from gateway.instruments.stress.checked_load import STEADY, CheckedLoad
from gateway.profile import format_parameter
from tests.support import RecordProperty, running_gateway

UNITS = [1, 2, 3, 4]
REQUESTS = 2000
FAULT_RATE = 0.05
TIMEOUT_MS = 30
DRAIN_MS = 80
LATE_MS = 50
"""A late reply starts after the response timeout and inside the drain that follows it: the
gateway hears it out and throws it away. (Later than any drain, no RTU master can tell a late
reply from the next one: RTU has no transaction id.)"""


def faulty_line_config(line_path: str) -> GatewayConfig:
    return GatewayConfig.model_validate(
        {
            "modbus_tcp": {"host": "127.0.0.1", "port": 0},
            "buses": [
                {
                    "name": "line1",
                    "port": line_path,
                    "baudrate": 115200,
                    "timeout_ms": TIMEOUT_MS,
                    "retries": 2,
                    "drain_ms": DRAIN_MS,
                    "char_timeout_ms": 5,
                }
            ],
            "drives": [{"name": f"drive{u}", "bus": "line1", "address": u} for u in UNITS],
        }
    )


async def test_under_5_percent_line_faults_every_value_is_right(
    record_property: RecordProperty,
) -> None:
    # Without wire time (the pty's own speed): faults and retries are the point here, and the
    # run takes half as long. The stress command runs with wire time.
    line = SimulatedLine(addresses=UNITS, baudrate=115200, response_delay_ms=1.0, wire_time=False)
    with line:
        line.set_line_faults(FAULT_RATE, seed=20261122, late_ms=LATE_MS)
        async with running_gateway(faulty_line_config(line.path)) as app:
            load = CheckedLoad(app.tcp.port, UNITS, clients=8, seed=7)
            started = time.monotonic()
            await asyncio.wait_for(load.run(asyncio.Event(), max_requests=REQUESTS), 60)
            elapsed = time.monotonic() - started
            bus = app.buses["line1"].stats
        line_stats = line.stats
        stats = load.stats
        requests = stats.requests[STEADY]
        errors = stats.errors[STEADY]
        figures = (
            f"{requests} requests, {line_stats['requests']} frames on the line, "
            f"{line_stats['faults_injected']} faults injected {line_stats['faults_by_kind']}, "
            f"{bus.retries} retries, {errors} errors seen by clients, {stats.wrong} wrong "
            f"values, {elapsed:.1f} s"
        )
        print(f"line faults: {figures}")
        record_property("figure:line faults", figures)
        assert stats.wrong == 0, stats.wrong_examples
        assert set(line_stats["faults_by_kind"]) == KINDS, "every kind of fault was injected"
        assert line_stats["faults_injected"] >= 0.03 * line_stats["requests"]
        assert errors < 0.001 * requests, stats.exceptions
        assert stats.answered == requests - errors
        # What the clients believe is what the drives hold: their last reads were right.
        with line.lock:
            for unit_id, register, possible in load.beliefs():
                held = line.drives[unit_id].parameter(format_parameter(register))
                assert possible is not None
                assert held in possible, f"unit {unit_id} {format_parameter(register)}"
