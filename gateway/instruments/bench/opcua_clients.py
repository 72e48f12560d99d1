"""The `opcua` cases' SCADA clients, run as a process of their own by `bench.opcua`:

    python -m gateway.instruments.bench.opcua_clients ENDPOINT FOLDER SESSIONS INTERVAL_MS N

Makes a client certificate and trusts it (as an admin would, into FOLDER/trusted), opens
SESSIONS sessions with Basic256Sha256 Sign & Encrypt, browses the gateway's drives once, and
subscribes each session to N values of every drive (each a monitored item; those the poller
fills first) at INTERVAL_MS. Prints `{"items": ..., "polled": ...}` (per session: items the
server took, of them values the poller fills) once all have subscribed; at the end of its
stdin, closes them and prints the same with `"notifications"` (all sessions')."""

from __future__ import annotations

import asyncio
import json
import logging
import shutil
import sys
from pathlib import Path

from asyncua import Client, Node, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography.x509.oid import ExtendedKeyUsageOID

from gateway.opcua.address_space import NAMESPACE

APPLICATION_URI = "urn:invt-gateway:bench:scada"


class Counter:
    def __init__(self) -> None:
        self.notifications = 0

    def datachange_notification(self, node: Node, value: object, data: object) -> None:
        self.notifications += 1


async def values_of_drives(client: Client, per_drive: int) -> tuple[list[Node], int]:
    """`per_drive` values of every drive (Objects → gateway → bus → drive → its values), those
    the poller fills first (Good now); and how many of them are."""
    ns = await client.get_namespace_index(NAMESPACE)
    gateway = client.get_node(ua.NodeId("gateway", ns))
    found, polled = [], 0
    # HasComponent only: a bus and a drive are also HasNotifier children (hierarchical too).
    part, obj, variable = ua.ObjectIds.HasComponent, ua.NodeClass.Object, ua.NodeClass.Variable
    for bus in await gateway.get_children(refs=part, nodeclassmask=obj):
        for drive in await bus.get_children(refs=part, nodeclassmask=obj):
            values = await drive.get_children(refs=part, nodeclassmask=variable)
            read = await client.read_attributes(values)
            good = [n for n, v in zip(values, read, strict=True) if v.StatusCode.is_good()]
            rest = [n for n in values if n not in good]
            found += (good + rest)[:per_drive]
            polled += min(len(good), per_drive)
    return found, polled


async def main(
    endpoint: str, folder: Path, sessions: int, interval_ms: int, per_drive: int
) -> None:
    logging.getLogger("asyncua").setLevel(logging.ERROR)  # its notes on the test certificate
    cert, key = folder / "scada-cert.der", folder / "scada-key.pem"
    await setup_self_signed_certificate(
        key,
        cert,
        APPLICATION_URI,
        "localhost",
        [ExtendedKeyUsageOID.CLIENT_AUTH],
        {"commonName": "invt-gateway bench SCADA"},
    )
    (folder / "trusted").mkdir(parents=True, exist_ok=True)
    shutil.copy(cert, folder / "trusted" / cert.name)
    counter = Counter()
    clients: list[Client] = []
    items, polled, nodes = 0, 0, list[Node]()
    for _ in range(sessions):
        client = Client(endpoint, timeout=30)
        client.application_uri = APPLICATION_URI
        await client.set_security(
            SecurityPolicyBasic256Sha256,
            str(cert),
            str(key),
            server_certificate=str(folder / "server-cert.der"),
            mode=ua.MessageSecurityMode.SignAndEncrypt,
        )
        await client.connect()
        clients.append(client)
        if not clients[1:]:  # the same nodes for every session
            nodes, polled = await values_of_drives(client, per_drive)
        subscription = await client.create_subscription(interval_ms, counter)
        handles = await subscription.subscribe_data_change(nodes)
        items = sum(isinstance(handle, int) for handle in handles)  # refused: a StatusCode
    print(json.dumps({"items": items, "polled": polled}), flush=True)
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)
    for client in clients:
        await client.disconnect()
    seen = {"items": items, "polled": polled, "notifications": counter.notifications}
    print(json.dumps(seen), flush=True)


if __name__ == "__main__":
    endpoint_, folder_, sessions_, interval_, per_drive_ = sys.argv[1:6]
    asyncio.run(main(endpoint_, Path(folder_), int(sessions_), int(interval_), int(per_drive_)))
