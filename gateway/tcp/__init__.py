"""The Modbus-TCP side: connections, MBAP framing, pipelining."""

from gateway.tcp.server import ModbusTcpServer, TcpSettings

__all__ = ["ModbusTcpServer", "TcpSettings"]
