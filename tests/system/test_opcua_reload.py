"""A reload (SIGHUP, `invt-gateway reload`) as a SCADA's OPC UA client sees it: a drive added
appears, a drive removed (or renamed) goes, and every other drive keeps its NodeIds and the
client's subscription to it keeps receiving, through asyncua's client on a real socket."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import pytest
from asyncua import ua

from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.profile.states import RunState
from gateway.settings import runtime_settings
from tests.support import running_gateway
from tests.support.console_support import OPERATOR_PASSWORD, USERS
from tests.support.opcua import configuration_file, make_client_certificate, trust
from tests.system.test_opcua import connected, drive_node, good, ns_of, until, value_of

pytestmark = pytest.mark.line(addresses=(1, 2, 3))


@pytest.fixture(scope="module")
def client_certificate(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return make_client_certificate(tmp_path_factory.mktemp("client"))


async def test_a_reload_adds_and_removes_drives_and_keeps_the_rest(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    file = configuration_file(line)
    async with running_gateway(GatewayConfig.model_validate(file)) as app:
        trust(app, client_certificate[0])
        async with connected(
            app, client_certificate, USERS[0]["name"], OPERATOR_PASSWORD
        ) as client:
            await until(lambda: good(client, "pump1.state"))
            await until(lambda: good(client, "fan2.state"))
            seen: asyncio.Queue[object] = asyncio.Queue()
            statuses: dict[str, list[int]] = {}

            class Handler:
                def datachange_notification(self, node: Any, value: object, data: Any) -> None:
                    status = data.monitored_item.Value.StatusCode.value
                    statuses.setdefault(node.nodeid.Identifier, []).append(status)
                    if node.nodeid.Identifier == "pump1.state":
                        seen.put_nowait(value)

            subscription = await client.create_subscription(100, Handler())
            # One subscription for both: the removed drive's item must not stop the other's.
            states = [await drive_node(client, f"{d}.state") for d in ("pump1", "fan2")]
            await subscription.subscribe_data_change(states)
            assert await asyncio.wait_for(seen.get(), 2) == "stopped"
            before = (await drive_node(client, "pump1")).nodeid

            # fan2 renamed blower2 (one removed, one added), mixer3 added, pump1 untouched.
            fan = file["drives"][1]
            drives = [file["drives"][0], {**fan, "name": "blower2"}]
            drives.append({"name": "mixer3", "bus": "line1", "address": 3})
            plan = await app.reload(
                runtime_settings(GatewayConfig.model_validate({**file, "drives": drives}))
            )
            assert "OPC UA nodes of drives added or removed" in plan.changed

            bus = client.get_node(ua.NodeId("bus:line1", await ns_of(client)))
            names = {(await n.read_browse_name()).Name for n in await bus.get_children()}
            assert names == {"pump1", "blower2", "mixer3"}
            gone = await value_of(client, "fan2.state")
            assert gone.StatusCode.value == ua.StatusCodes.BadNodeIdUnknown
            # Its subscriber was told, as OPC UA has it: the item's value went BadNodeIdUnknown.
            await until(lambda: _told(statuses, "fan2.state", ua.StatusCodes.BadNodeIdUnknown))
            await until(lambda: good(client, "blower2.output_frequency_hz"))
            await until(lambda: good(client, "mixer3.state"))
            mixer = await drive_node(client, "mixer3")
            assert await mixer.call_method(f"{await ns_of(client)}:RunForward") == "ok"
            assert line.drives[3].state(time.monotonic()) is RunState.RUNNING_FORWARD

            # pump1: the same node, its subscription still live.
            assert (await drive_node(client, "pump1")).nodeid == before
            pump = await drive_node(client, "pump1")
            assert await pump.call_method(f"{await ns_of(client)}:RunForward") == "ok"
            while await asyncio.wait_for(seen.get(), 3) != "running_forward":
                pass


async def _told(statuses: dict[str, list[int]], node_id: str, status: int) -> bool:
    """The last notification of `node_id`'s item had `status`."""
    return statuses.get(node_id, [None])[-1] == status
