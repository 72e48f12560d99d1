"""What `run` needs of this machine before it serves, checked without starting anything.

A file can validate key by key and still not start: two listeners on one port, a certificate
file that is missing or is not a certificate, a bind address that is not this machine's. `run`
finds these only as it binds and loads, and fails. So they are checked here, in one function
that `run` calls before it starts anything (exit code 4, one line each) and `check-config`, the
console's Check and Apply and every reload call, each refusing the configuration with the same
(key path, reason) pairs a validation error has:

    ports      the listeners (Modbus-TCP, its TLS listener, the console, /metrics) never two on
               one port of overlapping addresses (0.0.0.0 and :: overlap every address); port 0
               (a free one picked) never clashes
    files      each TLS file of a listener that starts is there, readable, and what its key says:
               a PEM certificate, its private key (unencrypted: nobody types a passphrase at a
               start), the key of that certificate, a CA file with at least one certificate
    addresses  each listener's host is an address of this machine (or a name that resolves to
               one): bound to port 0 a moment, as `run` would bind it
    extras     the OPC UA server's stack (asyncua, the `opcua` extra) is installed when
               `opcua.enabled`

Whether a port is free of other programs is not checked: the running gateway holds its own.
"""

from __future__ import annotations

import contextlib
import importlib.util
import socket
import ssl
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import UnsupportedAlgorithm
from cryptography.hazmat.primitives import serialization

from gateway.config.schema import GatewayConfig
from gateway.listen import cannot_listen

ANY_ADDRESS = frozenset({"0.0.0.0", "::", ""})

Problem = tuple[str, str]
"""(key path, reason), as `ConfigError.problems` has them."""


@dataclass(frozen=True, slots=True)
class Listener:
    service: str
    """As the gateway's own start-up errors name it ("Modbus-TCP", "the console")."""
    key: str
    """The configuration keys of its address: "modbus_tcp" for modbus_tcp.host/port."""
    host: str
    port: int


def startup_problems(config: GatewayConfig) -> list[Problem]:
    """Everything that would keep `run` from starting on this machine, in the file's order."""
    listeners = list(_listeners(config))
    return _port_clashes(listeners) + _tls_files(config) + _addresses(listeners) + _extras(config)


def _extras(config: GatewayConfig) -> list[Problem]:
    if config.opcua.enabled and importlib.util.find_spec("asyncua") is None:
        reason = "the OPC UA server needs asyncua: pip install 'invt-gateway[opcua]'"
        return [("opcua.enabled", reason)]
    return []


def _listeners(config: GatewayConfig) -> Iterator[Listener]:
    tcp = config.modbus_tcp
    if tcp.plain:
        yield Listener("Modbus-TCP", "modbus_tcp", tcp.host, tcp.port)
    if tcp.tls.enabled:
        host = tcp.host if tcp.tls.host is None else tcp.tls.host
        yield Listener("Modbus/TCP Security", "modbus_tcp.tls", host, tcp.tls.port)
    if config.console.enabled:
        yield Listener("the console", "console", config.console.host, config.console.port)
    if config.metrics.enabled:
        yield Listener("metrics and health", "metrics", config.metrics.host, config.metrics.port)
    if config.opcua.enabled:
        yield Listener("the OPC UA server", "opcua", config.opcua.host, config.opcua.port)


def _port_clashes(listeners: list[Listener]) -> list[Problem]:
    problems = []
    for index, listener in enumerate(listeners):
        for earlier in listeners[:index]:
            if listener.port and listener.port == earlier.port and _overlap(listener, earlier):
                problems.append(
                    (
                        f"{listener.key}.port",
                        f"{listener.port} is also {earlier.key}.port ({earlier.service} on "
                        f"{earlier.host}): two listeners on one port, {listener.service} could "
                        "not start; give each its own port",
                    )
                )
                break
    return problems


def _overlap(one: Listener, other: Listener) -> bool:
    return one.host == other.host or one.host in ANY_ADDRESS or other.host in ANY_ADDRESS


def _tls_files(config: GatewayConfig) -> list[Problem]:
    problems: list[Problem] = []
    tls = config.modbus_tcp.tls
    if tls.enabled and tls.cert_file and tls.key_file and tls.ca_file:
        problems += _certificate_and_key("modbus_tcp.tls", tls.cert_file, tls.key_file)
        problems += _ca_file("modbus_tcp.tls.ca_file", tls.ca_file)
    console = config.console
    if console.enabled and console.cert_file and console.key_file:
        problems += _certificate_and_key("console", console.cert_file, console.key_file)
    return problems


def _certificate_and_key(section: str, cert_file: str, key_file: str) -> list[Problem]:
    problems: list[Problem] = []
    cert = _read(f"{section}.cert_file", cert_file, problems)
    key = _read(f"{section}.key_file", key_file, problems)
    if cert is not None:
        try:
            x509.load_pem_x509_certificate(cert)
        except ValueError:
            problems.append((f"{section}.cert_file", f"{cert_file}: not a PEM certificate"))
    if key is not None:
        try:
            serialization.load_pem_private_key(key, password=None)
        except TypeError:
            problems.append(
                (f"{section}.key_file", f"{key_file}: the key is encrypted (give it unencrypted)")
            )
        except (ValueError, UnsupportedAlgorithm):
            problems.append((f"{section}.key_file", f"{key_file}: not a PEM private key"))
    if not problems:
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        try:
            context.load_cert_chain(cert_file, key_file)
        except ssl.SSLError as exc:
            problems.append(
                (
                    f"{section}.key_file",
                    f"{key_file}: not the key of {cert_file} ({exc.reason or exc})",
                )
            )
    return problems


def _ca_file(key: str, path: str) -> list[Problem]:
    problems: list[Problem] = []
    data = _read(key, path, problems)
    if data is not None:
        try:
            x509.load_pem_x509_certificates(data)
        except ValueError:
            problems.append((key, f"{path}: no PEM certificate in it"))
    return problems


def _read(key: str, path: str, problems: list[Problem]) -> bytes | None:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        problems.append((key, f"{path}: {exc.strerror or exc}"))
        return None


def _addresses(listeners: list[Listener]) -> list[Problem]:
    problems = []
    checked: set[str] = set()
    for listener in listeners:
        if listener.host in checked or listener.host in ANY_ADDRESS:
            continue
        checked.add(listener.host)
        try:
            _bind_a_moment(listener.host)
        except OSError as exc:
            keys = f"{listener.key}.host/port"
            error = cannot_listen(listener.service, listener.host, listener.port, keys, exc)
            problems.append((f"{listener.key}.host", str(error)))
    return problems


def _bind_a_moment(host: str) -> None:
    """Bind `host` on a free port and let go: what `run` does with its port, minus the port."""
    for family, kind, proto, _, address in socket.getaddrinfo(
        host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
    ):
        with contextlib.closing(socket.socket(family, kind, proto)) as probe:
            probe.bind(address)
