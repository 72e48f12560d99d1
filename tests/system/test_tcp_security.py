"""Modbus/TCP Security: the TLS listener, client certificates required, roles from the
certificate's role extension (or `role_map`), `access[].roles` limiting rules to them.

pymodbus's TLS client is the independent peer; the certificates are made by openssl with the
profile's role extension (OID 1.3.6.1.4.1.50316.802.1, a UTF8String).
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import ssl
import struct
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from pymodbus.client import AsyncModbusTlsClient

from gateway.config import GatewayConfig, MetricsConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.profile.states import RunState
from gateway.tcp.cert_roles import role_extension
from tests.support import RecordProperty, TcpClient, eventually, free_port, running_gateway
from tests.support.http import http_get
from tests.support.tls import client_with_role, make_ca, make_signed

pytestmark = pytest.mark.line(addresses=[1])

ACCELERATION_TIME = 0x000B  # P00.11


@dataclass(frozen=True)
class Pki:
    ca: Path
    server: tuple[Path, Path]
    operator: tuple[Path, Path]
    viewer: tuple[Path, Path]
    mapped: tuple[Path, Path]
    """No role extension: its role comes from role_map by its common name."""
    stranger: tuple[Path, Path]
    """Signed by another CA."""


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    directory = tmp_path_factory.mktemp("pki")
    ca = make_ca(directory, "ca")
    server = make_signed(
        directory, "gateway", ca, "subjectAltName=IP:127.0.0.1\nextendedKeyUsage=serverAuth\n"
    )
    rogue = make_ca(directory, "rogue")
    return Pki(
        ca=ca[0],
        server=server,
        operator=client_with_role(directory, "scada-1", ca, "operator"),
        viewer=client_with_role(directory, "dashboard", ca, "viewer"),
        mapped=client_with_role(directory, "hmi-2", ca, None),
        stranger=client_with_role(directory, "stranger", rogue, "operator"),
    )


def secure_config(line_path: str, pki: Pki, **tcp: Any) -> GatewayConfig:
    return GatewayConfig.model_validate(
        {
            "modbus_tcp": {
                **tcp,
                "host": "127.0.0.1",
                "port": 0,
                "tls": {
                    "enabled": True,
                    "port": 0,
                    "cert_file": str(pki.server[0]),
                    "key_file": str(pki.server[1]),
                    "ca_file": str(pki.ca),
                    "role_map": {"hmi-2": "viewer"},
                },
                "access": [
                    # Viewers read; their writes are refused (01H), their parameter writes 02H.
                    {
                        "roles": ["viewer"],
                        "functions": [6],
                        "registers": ["P00.00-P00.20"],
                        "allow": False,
                    },
                    {"roles": ["viewer"], "functions": [5, 6, 15, 16, 22, 23], "allow": False},
                ],
            },
            "buses": [{"name": "line1", "port": line_path, "baudrate": 115200}],
            "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        }
    )


def client_context(pki: Pki, identity: tuple[Path, Path] | None) -> ssl.SSLContext:
    context = ssl.create_default_context(cafile=str(pki.ca))
    if identity is not None:
        context.load_cert_chain(str(identity[0]), str(identity[1]))
    return context


@contextlib.asynccontextmanager
async def pymodbus_tls(port: int, context: ssl.SSLContext):  # type: ignore[no-untyped-def]
    client = AsyncModbusTlsClient("127.0.0.1", port=port, sslctx=context, retries=0, timeout=3)
    try:
        assert await client.connect()
        yield client
    finally:
        client.close()


def test_the_role_is_read_from_the_certificate(pki: Pki) -> None:
    der = ssl.PEM_cert_to_DER_cert(pki.operator[0].read_text())
    assert role_extension(der) == "operator"
    assert role_extension(ssl.PEM_cert_to_DER_cert(pki.viewer[0].read_text())) == "viewer"
    assert role_extension(ssl.PEM_cert_to_DER_cert(pki.mapped[0].read_text())) is None


async def test_an_operator_writes_and_a_viewer_is_refused(line: SimulatedLine, pki: Pki) -> None:
    async with running_gateway(secure_config(line.path, pki)) as app:
        port = app.tcp.tls_port
        assert port is not None
        async with pymodbus_tls(port, client_context(pki, pki.operator)) as operator:
            written = await operator.write_register(ACCELERATION_TIME, 150, device_id=1)
            assert not written.isError()
            read = await operator.read_holding_registers(ACCELERATION_TIME, count=1, device_id=1)
            assert read.registers == [150]
        for identity in (pki.viewer, pki.mapped):  # by its role extension, by role_map
            async with pymodbus_tls(port, client_context(pki, identity)) as viewer:
                read = await viewer.read_holding_registers(ACCELERATION_TIME, count=1, device_id=1)
                assert read.registers == [150]
                refused = await viewer.write_register(ACCELERATION_TIME, 999, device_id=1)
                assert refused.isError()
                assert refused.exception_code == 0x02  # the rule names the registers
                refused = await viewer.write_register(0x2000, 1, device_id=1)  # run: 01H
                assert refused.isError()
                assert refused.exception_code == 0x01
        with line.lock:
            assert line.drives[1].parameter("P00.11") == 150  # no viewer's write reached it
            assert line.drives[1].state(time.monotonic()) is RunState.STOPPED
        # The plain listener stays, and rules with roles don't apply to it.
        plain = await TcpClient.connect(app.tcp.port)
        assert await plain.read(1, ACCELERATION_TIME) == [150]
        await plain.close()


@pytest.mark.parametrize("who", ["no certificate", "another CA"])
async def test_without_a_trusted_certificate_there_is_no_connection(
    line: SimulatedLine, pki: Pki, who: str
) -> None:
    identity = None if who == "no certificate" else pki.stranger
    async with running_gateway(secure_config(line.path, pki)) as app:
        port = app.tcp.tls_port
        assert port is not None
        context = client_context(pki, identity)

        def ask() -> bytes:
            with socket.create_connection(("127.0.0.1", port), timeout=3) as raw:
                try:
                    with context.wrap_socket(raw, server_hostname="127.0.0.1") as tls:
                        tls.sendall(struct.pack(">HHHBBHH", 1, 0, 6, 1, 3, 0x2100, 1))
                        return tls.recv(256)
                except (ssl.SSLError, ConnectionError):
                    return b""

        assert await asyncio.to_thread(ask) == b""
        assert app.tcp.stats.accepted == 0  # the handshake failed: never a connection
        await eventually(lambda: app.tcp.stats.tls_handshakes_failed == 1, what="counted")


async def test_stalled_handshakes_are_closed_and_counted_while_a_client_is_served(
    line: SimulatedLine, pki: Pki, record_property: RecordProperty
) -> None:
    metrics_port = free_port()
    metrics = MetricsConfig(enabled=True, host="127.0.0.1", port=metrics_port)
    config = secure_config(line.path, pki, first_request_timeout_s=1)
    async with running_gateway(config.model_copy(update={"metrics": metrics})) as app:
        port = app.tcp.tls_port
        assert port is not None
        # Half a ClientHello each: a record header announcing 512 bytes, and 16 of them.
        half_hello = bytes.fromhex("16 03 01 02 00 01 00 01 fc 03 03") + bytes(5)
        stalled = []
        for _ in range(50):
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(half_hello)
            stalled.append((reader, writer, time.monotonic()))
        # Meanwhile an operator's client connects and is served.
        async with pymodbus_tls(port, client_context(pki, pki.operator)) as operator:
            read = await operator.read_holding_registers(ACCELERATION_TIME, count=1, device_id=1)
            assert not read.isError()
        closed_after = await asyncio.gather(
            *(_closed_after(reader, started) for reader, _, started in stalled)
        )
        for _, writer, _ in stalled:
            writer.close()
        assert max(closed_after) < 2.5, max(closed_after)
        assert min(closed_after) > 0.8, min(closed_after)
        await eventually(lambda: app.tcp.stats.tls_handshake_timeouts == 50, what="counted")
        _, _, text = await http_get(metrics_port, "/metrics")
        assert "invt_gateway_tcp_tls_handshake_timeouts_total 50.0" in text
        assert "invt_gateway_tcp_tls_handshakes_failed_total 0.0" in text
        assert app.tcp.stats.accepted == 1  # the operator; the stalled ones never had a slot
        record_property(
            "figure:stalled TLS handshakes",
            f"50 closed {min(closed_after):.2f}-{max(closed_after):.2f} s after connecting "
            f"(first_request_timeout_s 1), counted; a TLS client served meanwhile",
        )


async def _closed_after(reader: asyncio.StreamReader, started: float) -> float:
    """Seconds from `started` until the gateway closed the connection."""
    with contextlib.suppress(ConnectionError):  # aborted: a reset is a close too
        await asyncio.wait_for(reader.read(), 10)
    return time.monotonic() - started
