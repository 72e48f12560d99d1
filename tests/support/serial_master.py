"""A serial master's side of a line, with pyserial: a request written, its reply read to the length
its function code gives (as the gateway finds a reply's end)."""

from __future__ import annotations

import serial

from gateway.modbus.functions import NEED_MORE, rtu_reply_length


def read_reply(port: serial.Serial, request_length: int) -> bytes:
    """One whole reply, its end found by its function code as the gateway finds it."""
    reply = port.read(2)
    length = rtu_reply_length(reply, request_length)
    if length == NEED_MORE:
        reply += port.read(1)
        length = rtu_reply_length(reply, request_length)
    assert length > 0, f"no reply, or one of no known length: {reply.hex(' ')}"
    return reply + port.read(length - len(reply))


def exchange(port: serial.Serial, request: bytes) -> bytes:
    port.write(request)
    return read_reply(port, len(request))
