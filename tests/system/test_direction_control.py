"""RS-485 direction control (`buses[].rs485`): RTS switched around every request, in order and
with the configured delays, recorded by a port double (`rtsrecord://`: hardware is the only
other way to see RTS); and a port that refuses a mode gives an error naming the bus and port."""

from __future__ import annotations

import logging
import struct

import pytest
import serial

from gateway.bus.direction import DirectionControl, DirectionMode
from gateway.bus.line import LineSettings, SerialLine
from gateway.errors import PortError
from gateway.instruments.simulator import SimulatedLine
from gateway.modbus.rtu import build_frame
from gateway.modbus.timing import CharacterFormat
from tests.serial_doubles.protocol_rtsrecord import Serial
from tests.support import TcpClient, gateway_config, read_pdu, running_gateway

serial.protocol_handler_packages.append("tests.serial_doubles")

READ_STATE_WORD = build_frame(1, struct.pack(">BHH", 3, 0x2100, 1))
STOPPED = bytes.fromhex("03 02 00 03")
BEFORE_S = 0.002
AFTER_S = 0.001
FORMAT = CharacterFormat(19200, "E")


def line_settings(port: str, control: DirectionControl) -> LineSettings:
    return LineSettings(
        port=port,
        char_format=FORMAT,
        gap_s=FORMAT.t35_s,
        char_timeout_s=0.02,
        drain_s=0.05,
        turnaround_s=0.1,
        direction=control,
        name="line1",
    )


@pytest.mark.parametrize("high_for_tx", [True, False])
async def test_rts_is_raised_for_each_request_and_released_after_the_drain(
    high_for_tx: bool,
) -> None:
    control = DirectionControl(DirectionMode.RTS, high_for_tx, BEFORE_S, AFTER_S)
    with SimulatedLine(addresses=[1], baudrate=19200, wire_time=True) as sim:
        line = SerialLine(line_settings(f"rtsrecord://{sim.path}", control))
        line.open()
        try:
            for _ in range(3):
                exchange = await line.transact(READ_STATE_WORD, expect_reply=True, timeout_s=0.3)
                assert exchange.reply_pdu == STOPPED  # the drive heard it and answered
        finally:
            line.close()
    events = Serial.recorded.pop(sim.path)
    tx, rx = high_for_tx, not high_for_tx
    first_write = next(i for i, event in enumerate(events) if event.what == "write")
    # Opened listening: the driver off before anything is sent.
    assert [e.value for e in events[: first_write - 1] if e.what == "rts"][-1] == rx
    # Then, for every request: driver on, the frame, the drain, driver off, in that order.
    per_request = events[first_write - 1 :]
    steps = [(e.what, e.value) for e in per_request if e.what != "write"]
    assert steps == [("rts", tx), ("drained", None), ("rts", rx)] * 3
    assert [e.what for e in per_request] == ["rts", "write", "drained", "rts"] * 3
    for on, write, drained, off in zip(*[iter(per_request)] * 4, strict=True):
        assert write.value == READ_STATE_WORD
        assert write.at - on.at >= BEFORE_S  # the transceiver's set-up time
        assert drained.at >= write.at
        assert off.at - drained.at >= AFTER_S  # held through the last stop bit


async def test_a_pty_refuses_rts_control_with_a_clear_error() -> None:
    with SimulatedLine(addresses=[1], baudrate=19200) as sim:
        line = SerialLine(line_settings(sim.path, DirectionControl(DirectionMode.RTS)))
        with pytest.raises(PortError, match=rf"bus line1 \({sim.path}\) refuses RTS control"):
            line.open()
        assert not line.is_open


async def test_a_pty_refuses_the_kernel_mode_with_a_clear_error(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with SimulatedLine(addresses=[1], baudrate=115200) as sim:
        line = SerialLine(line_settings(sim.path, DirectionControl(DirectionMode.KERNEL)))
        with pytest.raises(PortError, match=r"refuses the kernel's RS-485 mode"):
            line.open()
        # The whole gateway keeps running: requests get 0BH, and the log says why.
        drives = [{"name": "pump1", "address": 1}]
        config = gateway_config(sim.path, drives, rs485={"mode": "kernel"})
        async with running_gateway(config) as app:
            client = await TcpClient.connect(app.tcp.port)
            assert await client.request(1, read_pdu(0x2100)) == bytes.fromhex("83 0B")
            await client.close()
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    expected = f"bus line1 ({sim.path}) refuses the kernel's RS-485 mode"
    assert any(expected in message for message in said), said
