"""pymodbus's own RTU server playing a meter: every type and order a device file knows, in
registers laid out by hand here (not by the gateway's codecs), for `tests/system/test_devices.py`.

Usage: python -m tests.peers.pymodbus_meter DEVICE BAUD UNIT. Prints "ready" once it serves.
The device file that describes it is `tests/fixtures/devices/test_meter.yaml`.
"""

from __future__ import annotations

import asyncio
import struct
import sys
from typing import Final

from pymodbus import FramerType
from pymodbus.datastore import ModbusDeviceContext, ModbusServerContext
from pymodbus.server import StartAsyncSerialServer

from tests.peers.pymodbus_rtu_slave import block

# Where the bytes of a big-endian value go, by order: for 4 bytes A B C D, for 8 bytes A...H.
ARRIVAL: Final[dict[int, dict[str, tuple[int, ...]]]] = {
    4: {"ABCD": (0, 1, 2, 3), "CDAB": (2, 3, 0, 1), "BADC": (1, 0, 3, 2), "DCBA": (3, 2, 1, 0)},
    8: {
        "ABCD": (0, 1, 2, 3, 4, 5, 6, 7),
        "CDAB": (6, 7, 4, 5, 2, 3, 0, 1),
        "BADC": (1, 0, 3, 2, 5, 4, 7, 6),
        "DCBA": (7, 6, 5, 4, 3, 2, 1, 0),
    },
}

# name → (holding address, struct code, order, value): what the meter holds.
NUMBERS: Final = {
    "setpoint": (0, "f", "ABCD", 230.5),
    "frequency": (2, "f", "CDAB", 49.75),
    "balance": (4, "i", "BADC", -123456),
    "counter": (6, "I", "DCBA", 3_000_000_000),
    "energy_wh": (8, "Q", "ABCD", 12_345_678_901_234_567),
    "drift": (12, "q", "CDAB", -9_876_543_210),
    "total": (16, "d", "DCBA", 1234.5678),
    "reactive": (20, "d", "BADC", -0.001),
}
SERIAL: Final = (24, b"MTR-0042")  # 4 registers, ABCD
STATUS: Final = (28, 0b1001)  # bit 0 running, bit 1 alarm, bit 3 tripped
MODE: Final = (29, 2)  # 0 off, 1 local, 2 remote
TEMPERATURE: Final = (30, -125)  # s16, tenths of a degree
FLOW: Final = (0, 12.25)  # input registers 0-1, f32 BADC
COILS: Final = (1, 0)
DISCRETE_INPUTS: Final = (1,)

EXPECTED: Final = {
    **{name: value for name, (_, _, _, value) in NUMBERS.items()},
    "serial": "MTR-0042",
    "running": True,
    "alarm": False,
    "tripped": True,
    "status": 0b1001,
    "mode": "remote",
    "temperature": -12.5,
    "flow": 12.25,
    "pump_on": True,
    "valve_open": False,
    "door_open": True,
}
"""Every point's value as the device file's point names it, as the gateway must publish it."""


def arranged(code: str, order: str, value: float) -> list[int]:
    data = struct.pack(">" + code, value)
    ordered = bytes(data[i] for i in ARRIVAL[len(data)][order])
    return list(struct.unpack(f">{len(ordered) // 2}H", ordered))


def holding() -> list[int]:
    words = [0] * 40
    for address, code, order, value in NUMBERS.values():
        for offset, word in enumerate(arranged(code, order, value)):
            words[address + offset] = word
    start, text = SERIAL
    words[start : start + 4] = struct.unpack(">4H", text)
    words[STATUS[0]] = STATUS[1]
    words[MODE[0]] = MODE[1]
    words[TEMPERATURE[0]] = TEMPERATURE[1] & 0xFFFF
    return words


def inputs() -> list[int]:
    words = [0] * 10
    words[FLOW[0] : FLOW[0] + 2] = arranged("f", "BADC", FLOW[1])
    return words


async def main(path: str, baudrate: int, unit: int) -> None:
    meter = ModbusDeviceContext(
        co=block(list(COILS) + [0] * 8),
        di=block(list(DISCRETE_INPUTS) + [0] * 8),
        hr=block(holding()),
        ir=block(inputs()),
    )
    context = ModbusServerContext(devices={unit: meter}, single=False)
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
    asyncio.run(main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3])))
