"""Which written registers have a RAM-only twin.

INVT drives keep parameters in EEPROM, which wears out after some 10⁵-10⁶ writes; a SCADA that
writes a set-point parameter every second would wear it out within days. Writing to the address
with the top bit set (P00.07 → 8007H) changes the value in RAM only. The communication registers
(2000H.., 2100H.., 3000H.., 5000H) are RAM already and have no such twin, although their high
byte looks like a parameter group (20H = 32).
"""

from __future__ import annotations

from gateway.profile.addressing import RAM_BIT, is_parameter_register, ram_address

# High bytes of the communication register blocks (PROTOCOL.md's register map).
COMMUNICATION_BLOCKS = frozenset({0x20, 0x21, 0x30, 0x50})


def ram_write_address(register: int) -> int:
    """The RAM-only twin of a parameter register; any other register unchanged."""
    if register & RAM_BIT or register >> 8 in COMMUNICATION_BLOCKS:
        return register
    if not is_parameter_register(register):
        return register
    return ram_address(register)
