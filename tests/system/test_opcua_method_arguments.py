"""RunForward and RunReverse take the set frequency as an input argument (`FrequencyHz`,
Double), declared as UaExpert shows it, carried as MQTT's `{"command": "run_forward",
"frequency_hz": ...}`: the set-point written, then the run, through the same checks."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from asyncua import ua

from gateway.instruments.simulator import SimulatedLine
from gateway.profile.states import RunState
from tests.support import running_gateway
from tests.support.console_support import OPERATOR_PASSWORD, USERS
from tests.support.opcua import configuration, make_client_certificate, trust
from tests.system.test_opcua import commands, connected, drive_node, good, ns_of, until

pytestmark = pytest.mark.line(addresses=(1, 2))


@pytest.fixture(scope="module")
def client_certificate(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    return make_client_certificate(tmp_path_factory.mktemp("client"))


async def test_run_forward_takes_a_frequency_argument(
    line: SimulatedLine, client_certificate: tuple[Path, Path]
) -> None:
    async with running_gateway(configuration(line)) as app:
        trust(app, client_certificate[0])
        operator = (USERS[0]["name"], OPERATOR_PASSWORD)
        async with connected(app, client_certificate, *operator) as client:
            ns = await ns_of(client)
            drive = await drive_node(client, "pump1")
            # Declared: what UaExpert shows in its call dialog.
            method = await drive.get_child(f"{ns}:RunForward")
            (argument,) = await (await method.get_child("0:InputArguments")).read_value()
            assert argument.Name == "FrequencyHz"
            assert argument.DataType == ua.NodeId(ua.ObjectIds.Double)
            stop = await drive.get_child(f"{ns}:Stop")
            names = [(await c.read_browse_name()).Name for c in await stop.get_children()]
            assert "InputArguments" not in names  # Stop takes none

            await until(lambda: good(client, "pump1.set_frequency_hz"))
            frequency = ua.Variant(25.0, ua.VariantType.Double)
            assert await drive.call_method(f"{ns}:RunForward", frequency) == "ok"
            events = await until(lambda: commands(app, 1))
            assert events[0].data["command"] == "run_forward"
            assert events[0].data["frequency_hz"] == 25.0  # one command, as MQTT's
            assert events[0].data["source"] == "opcua"
            assert line.drives[1].state(time.monotonic()) is RunState.RUNNING_FORWARD

            async def set_to_25() -> bool:
                value = await good(client, "pump1.set_frequency_hz")
                return value is not None and value.Value.Value == 25.0

            await until(set_to_25)

            # Beyond the drive's limits: refused by the same check as MQTT's, nothing written.
            too_high = ua.Variant(4000.0, ua.VariantType.Double)
            with pytest.raises(ua.UaStatusCodeError) as refused:
                await drive.call_method(f"{ns}:RunReverse", too_high)
            assert refused.value.code == ua.StatusCodes.BadOutOfRange
            assert line.drives[1].state(time.monotonic()) is RunState.RUNNING_FORWARD
            # Left out (a client that may): the run at the present set point.
            assert await drive.call_method(f"{ns}:RunReverse") == "ok"
