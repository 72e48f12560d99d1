"""The OPC UA 1.04 security policies beside Basic256Sha256: Aes128_Sha256_RsaOaep and
Aes256_Sha256_RsaPss, each mode, as asyncua's client connects with them (node-opcua's in
`test_opcua_node_client.py`); and a policy not listed is not offered."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import (
    SecurityPolicy,
    SecurityPolicyAes128Sha256RsaOaep,
    SecurityPolicyAes256Sha256RsaPss,
    SecurityPolicyBasic256Sha256,
)

from gateway.app import Application
from gateway.instruments.simulator import SimulatedLine
from gateway.opcua.address_space import NAMESPACE
from tests.support import running_gateway
from tests.support.console_support import USERS, VIEWER_PASSWORD
from tests.support.opcua import configuration, make_client_certificate, trust

pytestmark = pytest.mark.line(addresses=(1, 2))

AES = [
    "Aes128_Sha256_RsaOaep_Sign",
    "Aes128_Sha256_RsaOaep_SignAndEncrypt",
    "Aes256_Sha256_RsaPss_Sign",
    "Aes256_Sha256_RsaPss_SignAndEncrypt",
]
CLIENT_POLICY: dict[str, type[SecurityPolicy]] = {
    "Aes128_Sha256_RsaOaep": SecurityPolicyAes128Sha256RsaOaep,
    "Aes256_Sha256_RsaPss": SecurityPolicyAes256Sha256RsaPss,
    "Basic256Sha256": SecurityPolicyBasic256Sha256,
}


@pytest.fixture(scope="module")
def client_certificate(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return make_client_certificate(tmp_path_factory.mktemp("client"))


async def read_state(app: Application, certificate: tuple[Path, Path], endpoint: str) -> str:
    """pump1's state, read by a viewer over the endpoint `endpoint` (policy_mode)."""
    assert app.settings.opcua is not None
    policy, _, mode = endpoint.rpartition("_")
    client = Client(app.settings.opcua.endpoint, timeout=4)
    client.application_uri = "urn:invt-gateway:tests:client"
    await client.set_security(
        CLIENT_POLICY[policy],
        str(certificate[0]),
        str(certificate[1]),
        server_certificate=str(app.settings.opcua.certificate_file),
        mode=getattr(ua.MessageSecurityMode, mode),
    )
    client.set_user(USERS[1]["name"])
    client.set_password(VIEWER_PASSWORD)
    async with client:
        ns = await client.get_namespace_index(NAMESPACE)
        node = client.get_node(ua.NodeId("pump1.state", ns))
        for _ in range(100):
            value = await node.read_data_value(raise_on_bad_status=False)
            if value.StatusCode.is_good():
                return str(value.Value.Value)
            await asyncio.sleep(0.05)
    raise AssertionError("pump1.state never good")


async def test_each_aes_policy_and_mode_is_offered_and_connects(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line, security=AES)) as app:
        trust(app, client_certificate[0])
        for endpoint in AES:
            assert await read_state(app, client_certificate, endpoint) == "stopped", endpoint
        # What a client's endpoint list shows: those listed, no other.
        assert app.settings.opcua is not None
        url = app.settings.opcua.endpoint
        endpoints = await Client(url, timeout=4).connect_and_get_server_endpoints()
        offered = {
            f"{e.SecurityPolicyUri.rpartition('#')[2]}_{e.SecurityMode.name}" for e in endpoints
        }
        assert offered == set(AES)
        # Basic256Sha256 was not listed: a client asking for it gets no channel.
        with pytest.raises((TimeoutError, ua.UaError)):
            await read_state(app, client_certificate, "Basic256Sha256_SignAndEncrypt")
