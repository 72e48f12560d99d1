"""A simulated INVT drive line, behaving as the manuals describe, for tests and demos.

- `drive`: one drive's answers and behaviour (ramps, faults, parameters). Pure logic.
- `motor`: the output-frequency ramp.
- `framing`: where a request ends, on the drive's side of the line.
- `line_faults`: replies spoilt on purpose (CRC, truncated, wrong address, late, silence).
- `endpoint`: the pty (or serial device) the line is served on.
- `line`: `SimulatedLine`, the drives on one pty served from their own thread.
- `control`: the text commands `invt-gateway simulate` reads on stdin.
"""

from gateway.instruments.simulator.drive import SimulatedDrive
from gateway.instruments.simulator.line import SimulatedLine

__all__ = ["SimulatedDrive", "SimulatedLine"]
