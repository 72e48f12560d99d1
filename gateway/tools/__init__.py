"""Field tools: what a technician runs on a line, with the gateway's own RTU master.

- `masters`: one request at a time, on the serial line (`SerialLine`) or through a running
  gateway over Modbus-TCP (`--via tcp://host:port`).
- `points`: what a person types ("P00.11", "2100H", "output_frequency") → a register with its
  scale, unit and meaning; values both ways.
- `access`: read and write points, turning failures into what to check on site.
- `scan`: find the drives on a line.
- `advice`: the checklists those errors point to.
- `open`: the master the command-line arguments ask for.

This module itself holds only defaults the command-line parsers show, so `--help` stays light.
"""

SERIAL_TIMEOUT_MS = 500.0
VIA_TIMEOUT_MS = 3000.0
"""Through a gateway the answer may wait for the gateway's own retries on the line."""
SCAN_TIMEOUT_MS = 50.0
"""A silent address costs one of these in a scan: short, but above the drives' usual response
delay (P14.03, 5 ms from the factory) and a 16-word reply's first byte at 9600 baud."""
