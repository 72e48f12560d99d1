"""Modbus framing as pure functions: bytes in, bytes out, no I/O.

- `crc`: CRC-16/MODBUS.
- `functions`: what each function code's request and reply look like (lengths, write or read).
- `rtu`: RTU frames (address + PDU + CRC) and the end-of-reply rule.
- `mbap`: the Modbus-TCP header.
- `timing`: character time, t3.5 and wire time of a serial character format.
"""
