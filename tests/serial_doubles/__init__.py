"""pyserial URL handlers that stand in for hardware the tests can't have.

Registered with `serial.protocol_handler_packages.append("tests.serial_doubles")`; a URL
`rtsrecord:///dev/pts/N` then opens `protocol_rtsrecord.Serial` on that pty.
"""
