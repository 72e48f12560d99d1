"""What the OPC UA tests share: a gateway's configuration with the server on, a client's own
certificate (as UaExpert makes one on its first start), and an admin trusting it."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from asyncua.crypto.cert_gen import setup_self_signed_certificate
from cryptography.x509.oid import ExtendedKeyUsageOID

from gateway.app import Application
from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from tests.support import free_port
from tests.support.console_support import USERS


def configuration(line: SimulatedLine, **opcua: Any) -> GatewayConfig:
    return GatewayConfig.model_validate(configuration_file(line, **opcua))


def configuration_file(line: SimulatedLine, **opcua: Any) -> dict[str, Any]:
    """Two drives on the simulated line, the console's users, the OPC UA server on a free
    port of loopback: the file a person would write, as a dict."""
    return {
        "gateway_id": "opcua-test",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [
            {
                "name": "line1",
                "port": line.path,
                "baudrate": 19200,
                "parity": "E",
                "probe_max_s": 0.5,
                "offline_after": 2,
            }
        ],
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1},
            {"name": "fan2", "bus": "line1", "address": 2},
        ],
        "console": {"users": USERS},
        "opcua": {"enabled": True, "host": "127.0.0.1", "port": free_port(), **opcua},
    }


def make_client_certificate(folder: Path) -> tuple[Path, Path]:
    """A client's application certificate and key, as UaExpert makes one on its first start."""
    cert, key = folder / "client-cert.der", folder / "client-key.pem"
    asyncio.run(
        setup_self_signed_certificate(
            key,
            cert,
            "urn:invt-gateway:tests:client",
            "localhost",
            [ExtendedKeyUsageOID.CLIENT_AUTH],
            {"commonName": "invt-gateway tests"},
        )
    )
    return cert, key


def trust(app: Application, certificate: Path) -> None:
    """What an admin does: the client's certificate into the trusted folder."""
    assert app.settings.opcua is not None
    folder = app.settings.opcua.trusted_clients_dir
    folder.mkdir(parents=True, exist_ok=True)
    (folder / certificate.name).write_bytes(certificate.read_bytes())
