"""pymodbus's own RTU server as a slave on a serial device: an independent peer for the gateway.

Usage: python -m tests.peers.pymodbus_rtu_slave DEVICE BAUD UNIT [UNIT ...]
Holding register n holds 1000 + 10 * unit + n (n < 100); input register n holds 5000 + n;
coils alternate. Prints "ready" once it serves.
"""

from __future__ import annotations

import asyncio
import sys

from pymodbus import FramerType
from pymodbus.datastore import (
    ModbusDeviceContext,
    ModbusSequentialDataBlock,
    ModbusServerContext,
)
from pymodbus.server import StartAsyncSerialServer


def block(values: list[int]) -> ModbusSequentialDataBlock:
    """Values from the address 0 on the wire: pymodbus's data blocks start at 1 for it."""
    # pymodbus's ModbusSequentialDataBlock.__init__ has no annotations (py.typed all the same).
    return ModbusSequentialDataBlock(1, values)  # type: ignore[no-untyped-call]


def device(unit: int) -> ModbusDeviceContext:
    return ModbusDeviceContext(
        co=block([n % 2 for n in range(100)]),
        di=block([0] * 100),
        hr=block([1000 + 10 * unit + n for n in range(100)]),
        ir=block([5000 + n for n in range(100)]),
    )


async def main(path: str, baudrate: int, units: list[int]) -> None:
    context = ModbusServerContext(devices={u: device(u) for u in units}, single=False)
    print("ready", flush=True)
    await StartAsyncSerialServer(
        context,
        framer=FramerType.RTU,
        port=path,
        baudrate=baudrate,
        parity="N",
        stopbits=1,
        bytesize=8,
    )


if __name__ == "__main__":
    asyncio.run(main(sys.argv[1], int(sys.argv[2]), [int(u) for u in sys.argv[3:]]))
