"""The OPC UA server as a SCADA's client sees it, through asyncua's own client (the server's
stack) here and node-opcua's (another stack's) in `test_opcua_node_client.py`: the tree, values
from the poller with their units, a drive offline, writes and methods through the command path
with the role's say, anonymous and untrusted clients refused.

Each test runs the whole gateway in-process on a simulated line (a real pty) and talks to it on
a real socket, with Basic256Sha256 Sign & Encrypt and a client certificate the test trusts.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import hashlib
import logging
import os
import shutil
import signal
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from gateway.app import Application
from gateway.config import ENV_STATE_DIRECTORY, GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.opcua.address_space import NAMESPACE
from gateway.profile.states import RunState
from gateway.settings.opcua import OWN_FOLDER
from gateway.store import EventType
from gateway.store.records import StoredEvent
from tests.support import running_gateway
from tests.support.console_support import (
    OPERATOR_PASSWORD,
    USERS,
    VIEWER_PASSWORD,
    console_client,
)
from tests.support.opcua import (
    configuration,
    configuration_file,
    make_client_certificate,
    trust,
)
from tests.support.processes import gateway_process

pytestmark = pytest.mark.line(addresses=(1, 2))

OPERATOR = USERS[0]["name"]
VIEWER = USERS[1]["name"]
STOPS_WITHIN_S = 2.0


def connected(
    app: Application,
    certificate: tuple[Path, Path] | None,
    user: str | None = None,
    password: str | None = None,
) -> contextlib.AbstractAsyncContextManager[Client]:
    assert app.opcua is not None
    settings = app.settings.opcua
    assert settings is not None
    return connected_to(settings.endpoint, settings.certificate_file, certificate, user, password)


@contextlib.asynccontextmanager
async def connected_to(
    endpoint: str,
    server_cert: Path,
    certificate: tuple[Path, Path] | None,
    user: str | None = None,
    password: str | None = None,
) -> AsyncIterator[Client]:
    """A session of asyncua's client, Basic256Sha256 Sign & Encrypt with `certificate`, none
    without it."""
    client = Client(endpoint, timeout=4)
    client.application_uri = "urn:invt-gateway:tests:client"
    if certificate is not None:
        cert, key = certificate
        await client.set_security(
            SecurityPolicyBasic256Sha256,
            str(cert),
            str(key),
            server_certificate=str(server_cert),
            mode=ua.MessageSecurityMode.SignAndEncrypt,
        )
    if user is not None:
        client.set_user(user)
        client.set_password(password or "")
    async with client:
        yield client


@pytest.fixture(scope="module")
def client_certificate(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return make_client_certificate(tmp_path_factory.mktemp("client"))


async def drive_node(client: Client, name: str) -> Any:
    ns = await client.get_namespace_index(NAMESPACE)
    return client.get_node(ua.NodeId(name, ns))


async def value_of(client: Client, node_id: str) -> ua.DataValue:
    ns = await client.get_namespace_index(NAMESPACE)
    return await client.get_node(ua.NodeId(node_id, ns)).read_data_value(raise_on_bad_status=False)


async def until(check: Any, timeout_s: float = 5.0) -> Any:
    """`check()`'s first truthy answer, asked every 50 ms."""
    deadline = asyncio.get_running_loop().time() + timeout_s
    while True:
        found = await check()
        if found:
            return found
        if asyncio.get_running_loop().time() > deadline:
            raise AssertionError(f"not within {timeout_s} s")
        await asyncio.sleep(0.05)


async def test_the_tree_mirrors_the_gateway_with_polled_values_and_units(
    line: SimulatedLine, client_certificate: tuple[Path, Path], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    async with running_gateway(configuration(line)) as app:
        assert app.settings.opcua is not None
        made = app.settings.opcua.certificate_file.read_bytes()  # on this first start
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            ns = await ns_of(client)
            gateway = await client.nodes.objects.get_child([f"{ns}:opcua-test"])
            bus = await gateway.get_child([f"{ns}:line1"])
            names = {(await d.read_browse_name()).Name for d in await bus.get_children()}
            assert names == {"pump1", "fan2"}
            frequency = await until(lambda: good(client, "pump1.output_frequency_hz"))
            assert frequency.Value.VariantType == ua.VariantType.Double
            read_at = frequency.SourceTimestamp
            assert abs(datetime.datetime.now(datetime.UTC) - read_at).total_seconds() < 5
            state = await until(lambda: good(client, "pump1.state"))
            assert state.Value.Value == "stopped"
            fault = await until(lambda: good(client, "pump1.fault_name"))
            assert fault.Value.Value == "none"
            units = await value_of(client, "pump1.output_frequency_hz.EngineeringUnits")
            assert units.Value.Value.DisplayName.Text == "Hz"
            assert units.Value.Value.UnitId == 4740186  # UNECE HTZ
            word = await until(lambda: good(client, "pump1.state_word_1"))
            assert word.Value.VariantType == ua.VariantType.UInt16
        stopping = time.monotonic()
    assert time.monotonic() - stopping < STOPS_WITHIN_S
    said = [r.getMessage() for r in caplog.records if "thumbprint" in r.getMessage()]
    assert said == [
        f"OPC UA server certificate thumbprint (SHA-1): {hashlib.sha1(made).hexdigest()}"
    ]
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert errors == []


async def test_the_state_is_a_multistate_discrete_and_frequencies_have_their_range(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line)) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            state = await until(lambda: good(client, "pump1.run_state"))
            assert state.Value.VariantType == ua.VariantType.UInt32
            words = (await value_of(client, "pump1.run_state.EnumStrings")).Value.Value
            assert words[state.Value.Value].Text == "stopped"
            assert [w.Text for w in words][1:3] == ["running_forward", "running_reverse"]
            node = await drive_node(client, "pump1.run_state")
            kind = await node.read_type_definition()
            assert kind == ua.NodeId(ua.ObjectIds.MultiStateDiscreteType)
            maximum = line.drives[1].parameter("P00.03") / 100  # max frequency, as set
            for key in ("set_frequency_hz", "output_frequency_hz"):
                eu_range = (await value_of(client, f"pump1.{key}.EURange")).Value.Value
                assert (eu_range.Low, eu_range.High) == (0.0, maximum)


async def ns_of(client: Client) -> int:
    return int(await client.get_namespace_index(NAMESPACE))


async def good(client: Client, node_id: str) -> ua.DataValue | None:
    value = await value_of(client, node_id)
    return value if value.StatusCode.is_good() else None


async def test_an_offline_drive_says_bad_communication_error_then_good_again(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line)) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            await until(lambda: good(client, "fan2.output_current_a"))
            seen: asyncio.Queue[Any] = asyncio.Queue()

            class Handler:
                def event_notification(self, event: Any) -> None:
                    seen.put_nowait(event)

            subscription = await client.create_subscription(100, Handler())
            kind = await drive_node(client, "DriveEventType")
            await subscription.subscribe_events(await drive_node(client, "bus:line1"), kind)
            line.set_dead(2, True)

            async def bad() -> ua.DataValue | None:
                value = await value_of(client, "fan2.output_current_a")
                code = ua.StatusCodes.BadCommunicationError
                return value if value.StatusCode.value == code else None

            await until(bad, 10)
            assert await good(client, "pump1.output_current_a") is not None  # its neighbour
            parameter = await value_of(client, "fan2.Parameters.P00.03")  # asked of the line
            assert parameter.StatusCode.value == ua.StatusCodes.BadCommunicationError
            line.set_dead(2, False)
            await until(lambda: good(client, "fan2.output_current_a"), 10)
            lost = await asyncio.wait_for(seen.get(), 2)
            back = await asyncio.wait_for(seen.get(), 5)
            assert (lost.SourceName, lost.Kind, lost.Severity) == ("fan2", "drive_offline", 600)
            assert (back.Message.Text, back.Severity) == ("online again", 200)  # heard on its bus


async def test_a_subscription_sees_a_method_call_run_the_drive(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line)) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, OPERATOR, OPERATOR_PASSWORD) as client:
            await until(lambda: good(client, "pump1.state"))
            seen: asyncio.Queue[object] = asyncio.Queue()

            class Handler:
                def datachange_notification(
                    self, node: object, value: object, data: object
                ) -> None:
                    seen.put_nowait(value)

            subscription = await client.create_subscription(100, Handler())
            state = await drive_node(client, "pump1.state")
            await subscription.subscribe_data_change(state)
            assert await asyncio.wait_for(seen.get(), 2) == "stopped"
            asked_by: list[str] = []  # who the bus's traffic monitor and metrics say asked
            for bus in app.buses.values():
                bus.add_request_observer(lambda *done: asked_by.append(done[3]))
            frequency = await drive_node(client, "pump1.set_frequency_hz")
            await frequency.write_value(ua.Variant(20.0, ua.VariantType.Double))
            drive = await drive_node(client, "pump1")
            answer = await drive.call_method(f"{await ns_of(client)}:RunForward")
            assert answer == "ok"
            while await asyncio.wait_for(seen.get(), 3) != "running_forward":
                pass  # stopped, then the state the command brings, as the poller reads it
            assert line.drives[1].state(time.monotonic()) is RunState.RUNNING_FORWARD
            events = await until(lambda: commands(app, 2))
            assert [e.data.get("command") for e in events] == ["run_forward", None]
            assert events[1].data["frequency_hz"] == 20.0
            assert {e.data["source"] for e in events} == {"opcua"}
            assert {e.data["result"] for e in events} == {"ok"}
            assert {e.data["user"] for e in events} == {OPERATOR}  # who, in the audit
            assert "opcua" in asked_by  # the commands' requests, named for where they came from
            assert "mqtt" not in asked_by


async def commands(app: Application, count: int) -> list[StoredEvent] | None:
    """The `command` events, newest first, once there are `count`."""
    found = await app.events.recent_events(10, types=[EventType.COMMAND])
    return found if len(found) >= count else None


async def test_a_viewer_may_read_but_not_write_or_call(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line)) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            frequency = await drive_node(client, "pump1.set_frequency_hz")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await frequency.write_value(ua.Variant(20.0, ua.VariantType.Double))
            drive = await drive_node(client, "pump1")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await drive.call_method(f"{await ns_of(client)}:RunForward")
        assert line.drives[1].state(time.monotonic()) is RunState.STOPPED


async def test_an_out_of_range_set_point_is_refused_by_the_model_s_table(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line)) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, OPERATOR, OPERATOR_PASSWORD) as client:
            frequency = await drive_node(client, "pump1.set_frequency_hz")
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await frequency.write_value(ua.Variant(-5.0, ua.VariantType.Double))
            assert refused.value.code in (
                ua.StatusCodes.BadInvalidArgument,
                ua.StatusCodes.BadOutOfRange,
            )


async def test_anonymous_is_refused_unless_turned_on_and_then_reads_only(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line)) as app:
        trust(app, client_certificate[0])
        with pytest.raises(ua.UaStatusCodeError):
            async with connected(app, client_certificate):
                pass
    async with running_gateway(configuration(line, anonymous=True)) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate) as client:
            await until(lambda: good(client, "pump1.state"))
            frequency = await drive_node(client, "pump1.set_frequency_hz")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await frequency.write_value(ua.Variant(20.0, ua.VariantType.Double))


async def test_an_untrusted_client_is_refused_and_its_certificate_kept_for_trusting(
    line: SimulatedLine, client_certificate: tuple[Path, Path], caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    async with running_gateway(configuration(line)) as app:
        assert app.settings.opcua is not None
        rejected = app.settings.opcua.rejected_clients_dir
        with pytest.raises(ua.uaerrors.BadCertificateUntrusted):
            async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD):
                pass
        kept = list(rejected.iterdir())
        assert len(kept) == 1
        assert kept[0].read_bytes() == client_certificate[0].read_bytes()
        kept[0].rename(app.settings.opcua.trusted_clients_dir / kept[0].name)  # the admin trusts it
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            assert await until(lambda: good(client, "pump1.state"))


async def test_security_none_only_when_listed_and_then_with_a_warning(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    async with running_gateway(configuration(line)) as app:
        with pytest.raises(ua.UaError) as refused:  # no endpoint without security is offered
            async with connected(app, None, VIEWER, VIEWER_PASSWORD):
                pass
        assert "No matching endpoints" in str(refused.value)
    assert not [r for r in caplog.records if "policy None" in r.getMessage()]
    listed = configuration(line, security=["None", "Basic256Sha256_SignAndEncrypt"])
    async with (
        running_gateway(listed) as app,
        connected(app, None, VIEWER, VIEWER_PASSWORD) as client,
    ):
        assert await until(lambda: good(client, "pump1.state"))
    warned = [r.getMessage() for r in caplog.records if "policy None" in r.getMessage()]
    assert warned == [
        "OPC UA: security policy None is offered (opcua.security): no signing, no encryption, "
        "passwords in clear on the network"
    ]


async def test_connections_and_subscriptions_are_bounded(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    bounded = configuration(line, max_connections=1, max_subscriptions=1, max_monitored_items=3)
    async with running_gateway(bounded) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            subscription = await client.create_subscription(500, None)
            with pytest.raises(ua.uaerrors.BadTooManySubscriptions):
                await client.create_subscription(500, None)
            keys = ("state", "fault_code", "output_current_a", "bus_voltage_v")
            nodes = [await drive_node(client, f"pump1.{key}") for key in keys]
            made = await subscription.subscribe_data_change(nodes[:2])
            assert all(isinstance(handle, int) for handle in made)
            more = await subscription.subscribe_data_change(nodes[2:])
            assert isinstance(more[0], int)  # the third: the session's last one
            assert more[1] == ua.StatusCode(ua.StatusCodes.BadTooManyMonitoredItems)
            with pytest.raises((ConnectionError, OSError, asyncio.TimeoutError)):
                async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD):
                    pass
            assert await until(lambda: good(client, "pump1.state"))  # the first is still served


async def test_the_service_serves_opcua_and_stops_within_2_s(
    line: SimulatedLine, client_certificate: tuple[Path, Path], tmp_path: Path
) -> None:
    """`invt-gateway run` as systemd starts it: asyncua loaded because `opcua:` asks for it,
    the certificate made in the state directory, a client served, SIGTERM obeyed cleanly."""
    config = configuration_file(line)
    own = Path(os.environ[ENV_STATE_DIRECTORY]) / OWN_FOLDER
    (own / "trusted").mkdir(parents=True)
    shutil.copy(client_certificate[0], own / "trusted")
    endpoint = f"opc.tcp://127.0.0.1:{config['opcua']['port']}/invt-gateway"
    with gateway_process(config, tmp_path) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        server_cert = own / "server-cert.der"
        async with connected_to(
            endpoint, server_cert, client_certificate, VIEWER, VIEWER_PASSWORD
        ) as client:
            assert await until(lambda: good(client, "pump1.state"))
        stopping = time.monotonic()
        gateway.signal(signal.SIGTERM)
        code = await asyncio.to_thread(gateway.wait, STOPS_WITHIN_S + 1)
        stopped_after = time.monotonic() - stopping
    assert code == 0, gateway.log.text
    assert stopped_after < STOPS_WITHIN_S, gateway.log.text
    thumbprint = hashlib.sha1(server_cert.read_bytes()).hexdigest()
    assert f"OPC UA server certificate thumbprint (SHA-1): {thumbprint}" in gateway.log.text
    for bad in (" ERROR ", " CRITICAL ", "Traceback"):
        assert bad not in gateway.log.text, gateway.log.text


async def test_a_fault_is_an_event_on_the_drive_raised_then_cleared_in_words(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line)) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            await until(lambda: good(client, "pump1.state"))
            seen: asyncio.Queue[Any] = asyncio.Queue()

            class Handler:
                def event_notification(self, event: Any) -> None:
                    seen.put_nowait(event)

            subscription = await client.create_subscription(100, Handler())
            kind = await drive_node(client, "DriveEventType")
            drive = await drive_node(client, "pump1")
            await subscription.subscribe_events(drive, kind)
            on_server = await client.create_subscription(100, Handler())
            await on_server.subscribe_events(client.nodes.server, kind)
            line.inject_fault(1, 11)
            raised = await asyncio.wait_for(seen.get(), 5)
            again = await asyncio.wait_for(seen.get(), 2)  # the same event, on the Server object
            assert raised.EventId == again.EventId
            assert (raised.Kind, raised.FaultCode, raised.FaultName) == ("fault_raised", 11, "OL1")
            assert raised.Severity == 800
            assert raised.SourceName == "pump1"
            assert raised.Message.Text == "fault raised: OL1: motor overload (code 11)"
            line.clear_fault(1)
            cleared = await asyncio.wait_for(seen.get(), 5)
            assert (cleared.Kind, cleared.Severity) == ("fault_cleared", 200)
            assert cleared.Message.Text == "fault cleared: OL1: motor overload (code 11)"


async def test_parameters_are_nodes_read_from_the_drive_on_demand_and_written_through_the_checks(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line)) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, OPERATOR, OPERATOR_PASSWORD) as client:
            ns = await ns_of(client)
            drive = await drive_node(client, "pump1")
            folder = await drive.get_child([f"{ns}:Parameters"])
            names = [(await n.read_browse_name()).Name for n in await folder.get_children()]
            assert names[:3] == ["P00.00", "P00.01", "P00.02"]
            maximum = await value_of(client, "pump1.Parameters.P00.03")  # not polled: read once
            assert maximum.StatusCode.is_good()
            assert maximum.Value.VariantType == ua.VariantType.Double
            assert maximum.Value.Value == line.drives[1].parameter("P00.03") / 100
            again = await value_of(client, "pump1.Parameters.P00.03")
            assert again.SourceTimestamp == maximum.SourceTimestamp  # kept, not read again
            units = await value_of(client, "pump1.Parameters.P00.03.EngineeringUnits")
            assert units.Value.Value.DisplayName.Text == "Hz"
            eu_range = (await value_of(client, "pump1.Parameters.P00.11.EURange")).Value.Value
            assert (eu_range.Low, eu_range.High) == (0.0, 3600.0)
            node = await drive_node(client, "pump1.Parameters.P00.11")
            description = await node.read_description()
            assert description.Text == "acceleration time 1"
            await node.write_value(ua.Variant(12.5, ua.VariantType.Double))
            assert line.drives[1].parameter("P00.11") == 125
            written = await value_of(client, "pump1.Parameters.P00.11")
            assert written.Value.Value == 12.5  # read again after the write
            with pytest.raises(ua.uaerrors.BadOutOfRange):  # the table's range: 0.0 ... 3600.0
                await node.write_value(ua.Variant(4000.0, ua.VariantType.Double))
            events = await until(lambda: commands(app, 1))
            assert (events[0].data["parameter"], events[0].data["user"]) == ("P00.11", OPERATOR)
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            node = await drive_node(client, "pump1.Parameters.P00.11")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await node.write_value(ua.Variant(20.0, ua.VariantType.Double))


async def test_the_console_s_diagnostics_show_the_opcua_sessions(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    config = configuration_file(line)
    config["console"] |= {"enabled": True, "host": "127.0.0.1", "port": 0}
    async with running_gateway(GatewayConfig.model_validate(config)) as app:
        trust(app, client_certificate[0])
        async with console_client(app) as web:
            assert (await web.login(VIEWER, VIEWER_PASSWORD)).status == 200
            before = (await web.get_json("/api/diagnostics"))["opcua"]
            assert before == {"sessions": []}
            logged_in = datetime.datetime.now(datetime.UTC)
            async with connected(app, client_certificate, OPERATOR, OPERATOR_PASSWORD):
                (session,) = (await web.get_json("/api/diagnostics"))["opcua"]["sessions"]
                assert (session["user"], session["role"]) == (OPERATOR, "operator")
                since = datetime.datetime.fromisoformat(session["since"])
                assert abs((since - logged_in).total_seconds()) < 5
            assert (await web.get_json("/api/diagnostics"))["opcua"] == {"sessions": []}


async def test_the_parameters_shown_are_those_listed(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    with pytest.raises(ValueError, match="'X00' is not a group"):
        configuration(line, parameters=["X00"])
    async with running_gateway(configuration(line, parameters=["p00.03", "P01"])) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            folder = await (await drive_node(client, "pump1")).get_child(
                [f"{await ns_of(client)}:Parameters"]
            )
            names = [(await n.read_browse_name()).Name for n in await folder.get_children()]
            assert names[0] == "P00.03"
            assert {name.split(".")[0] for name in names[1:]} == {"P01"}
    async with running_gateway(configuration(line, parameters="none")) as app:
        trust(app, client_certificate[0])
        async with connected(app, client_certificate, VIEWER, VIEWER_PASSWORD) as client:
            drive = await drive_node(client, "pump1")
            children = [(await n.read_browse_name()).Name for n in await drive.get_children()]
            assert "Parameters" not in children
            assert "state" in children
