"""A reload (SIGHUP, `invt-gateway reload`) as a SCADA's OPC UA client sees it: a drive added
appears, a drive removed (or renamed) goes, a drive changed is made again with the same NodeIds,
and the client's subscriptions to the drives that stay (changed or not) keep receiving, through
asyncua's client on a real socket."""

from __future__ import annotations

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

pytestmark = pytest.mark.line(addresses=(1, 2, 3, 4))


@pytest.fixture(scope="module")
def client_certificate(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return make_client_certificate(tmp_path_factory.mktemp("client"))


class Notifications:
    """What a subscription heard, per NodeId text: (value, StatusCode) in order."""

    def __init__(self) -> None:
        self.heard: dict[str, list[tuple[object, int]]] = {}

    def datachange_notification(self, node: Any, value: object, data: Any) -> None:
        status = data.monitored_item.Value.StatusCode.value
        self.heard.setdefault(node.nodeid.Identifier, []).append((value, status))

    async def last(self, node_id: str, expected: tuple[object, int]) -> bool:
        return self.heard.get(node_id, [(None, 0)])[-1] == expected


async def test_a_reload_adds_removes_and_changes_drives_and_keeps_the_rest(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    file = configuration_file(line)
    file["drives"].append({"name": "mixer3", "bus": "line1", "address": 3})
    async with running_gateway(GatewayConfig.model_validate(file)) as app:
        trust(app, client_certificate[0])
        operator = (USERS[0]["name"], OPERATOR_PASSWORD)
        async with connected(app, client_certificate, *operator) as client:
            names = ("pump1", "fan2", "mixer3")
            for name in names:
                await until(lambda name=name: good(client, f"{name}.state"))
            notifications = Notifications()
            subscription = await client.create_subscription(100, notifications)
            # One subscription for all three: the removed drive's item must not stop the rest.
            await subscription.subscribe_data_change(
                [await drive_node(client, f"{name}.state") for name in names]
            )
            for name in names:
                await until(lambda name=name: notifications.last(f"{name}.state", ("stopped", 0)))
            before = (await drive_node(client, "pump1")).nodeid

            # pump1 untouched, fan2 renamed blower2 (one removed, one added), mixer3 changed
            # (a key of its own: removed and added again), conveyor4 added.
            pump, fan, mixer = file["drives"]
            drives = [pump, {**fan, "name": "blower2"}, {**mixer, "cache_max_age_ms": 500}]
            drives.append({"name": "conveyor4", "bus": "line1", "address": 4})
            new = GatewayConfig.model_validate({**file, "drives": drives})
            plan = await app.reload(runtime_settings(new))
            assert "OPC UA nodes of drives added or removed" in plan.changed

            ns = await ns_of(client)
            bus = client.get_node(ua.NodeId("bus:line1", ns))
            shown = {(await n.read_browse_name()).Name for n in await bus.get_children()}
            assert shown == {"pump1", "blower2", "mixer3", "conveyor4"}
            gone = await value_of(client, "fan2.state")
            assert gone.StatusCode.value == ua.StatusCodes.BadNodeIdUnknown
            # Its subscriber was told, as OPC UA has it: the item's value went BadNodeIdUnknown.
            told = (None, ua.StatusCodes.BadNodeIdUnknown)
            await until(lambda: notifications.last("fan2.state", told))
            await until(lambda: good(client, "blower2.output_frequency_hz"))
            await until(lambda: good(client, "conveyor4.state"))
            conveyor = await drive_node(client, "conveyor4")
            assert await conveyor.call_method(f"{ns}:RunForward") == "ok"
            assert line.drives[4].state(time.monotonic()) is RunState.RUNNING_FORWARD

            # pump1: the same node, its item still live; mixer3: made again, its item moved on.
            assert (await drive_node(client, "pump1")).nodeid == before
            running = ("running_forward", 0)
            for name in ("pump1", "mixer3"):
                drive = await drive_node(client, name)
                assert await drive.call_method(f"{ns}:RunForward") == "ok"
                await until(lambda name=name: notifications.last(f"{name}.state", running))


async def test_a_reload_whose_nodes_fail_to_follow_is_applied_and_says_what_needs_a_restart(
    line: SimulatedLine, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The drives change on the line, the metrics and MQTT; if the address space can't follow
    (a bug, asyncua's trouble), the reload still answers, naming OPC UA as waiting for a
    restart, and the added drive is served on Modbus-TCP all the same."""
    file = configuration_file(line)
    async with running_gateway(GatewayConfig.model_validate(file)) as app:
        assert app.opcua is not None

        async def fails(*_changes: object) -> None:
            raise RuntimeError("the address space refused it")

        monkeypatch.setattr(app.opcua, "drives_changed", fails)
        file["drives"].append({"name": "conveyor4", "bus": "line1", "address": 4})
        plan = await app.reload(runtime_settings(GatewayConfig.model_validate(file)))
        assert [drive.name for drive in plan.added] == ["conveyor4"]
        assert any("opcua" in item for item in plan.restart_needed)
        assert "restart needed for" in plan.summary
        assert "conveyor4" in {drive.name for drive in app.settings.drives}
