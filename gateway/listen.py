"""Binding a listening port, with one line a person can act on when it fails.

A socket error alone ("[Errno 98] error while attempting to bind on address ...") names neither
which of the gateway's ports it was nor what to do; this names the service, the address, the
port, the configuration keys and the likely cause.
"""

from __future__ import annotations

import errno
import socket

from gateway.errors import CannotListen

PRIVILEGED_PORTS = 1024


def cannot_listen(service: str, host: str, port: int, keys: str, exc: OSError) -> CannotListen:
    """The error for `service` (e.g. "Modbus-TCP") failing to listen on host:port.

    `keys` names where the address comes from (e.g. "modbus_tcp.host/port"), so the reader knows
    what to change.
    """
    where = f"{service} cannot listen on {host}:{port}"
    return CannotListen(f"{where}: {_cause(host, port, keys, exc)}")


def _cause(host: str, port: int, keys: str, exc: OSError) -> str:
    if isinstance(exc, socket.gaierror):
        return f"{host!r} is not an address or a known host name (check {keys})"
    if exc.errno == errno.EADDRINUSE:
        return (
            f"port {port} is already in use, by another invt-gateway (a demo?) or another "
            f"program (`ss -ltnp 'sport = :{port}'` shows which); stop it or change {keys}"
        )
    if exc.errno == errno.EACCES and 0 < port < PRIVILEGED_PORTS:
        return (
            f"permission denied: ports below {PRIVILEGED_PORTS} need root or "
            f"CAP_NET_BIND_SERVICE (the systemd unit grants it), or use a port such as 5020 "
            f"({keys})"
        )
    if exc.errno == errno.EADDRNOTAVAIL:
        return (
            f"{host} is not an address of this machine (check {keys}; 0.0.0.0 listens on all "
            f"of them)"
        )
    reason = exc.strerror or str(exc)
    return f"{reason} (check {keys})"
