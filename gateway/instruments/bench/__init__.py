"""`invt-gateway bench`: how close the gateway runs the RS-485 line to its physical limit.

- `wire`: the line's theoretical maximum for a case (bytes, character format, gaps, delays).
- `processes`: the simulated line and the gateway as real subprocesses, and their CPU and memory.
- `load`: Modbus-TCP clients that check every value they receive.
- `cases`: the matrix of cases and running one.
- `report`: the table.
- `instructions`: `--instructions`, the gateway's instructions per transaction (callgrind).
"""
