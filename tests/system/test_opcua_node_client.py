"""The OPC UA server against a client that is not ours: node-opcua's (npm node-opcua-client,
tests/peers/opcua_js/client.js), over Basic256Sha256 Sign & Encrypt and Sign, logged in as the
console's users: browse, read, write, subscribe, call, a viewer refused, anonymous refused,
its own certificate refused until an admin trusts it.

node-opcua makes its application certificate on its first connection (one per module here),
which each test's gateway trusts, as an admin would, before the test begins.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest

from gateway.app import Application
from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.opcua.address_space import NAMESPACE
from tests.support import running_gateway
from tests.support.console_support import OPERATOR_PASSWORD, USERS, VIEWER_PASSWORD
from tests.support.opcua import configuration

PEER = Path(__file__).parent.parent / "peers" / "opcua_js"
OPERATOR = USERS[0]["name"]
VIEWER = USERS[1]["name"]
pytestmark = pytest.mark.line(addresses=(1, 2))


Heard = Callable[[dict[str, Any]], Awaitable[None]]


async def node_client(
    app: Application, pki: Path, heard: Heard | None = None, **job: Any
) -> list[dict[str, Any]]:
    """One run of node-opcua's client: its session's answer, then one per step (and what an
    "events" step says as it goes, each handed to `heard` as it comes)."""
    node = shutil.which("node")
    if node is None or not (PEER / "node_modules" / "node-opcua-client").is_dir():
        pytest.fail(
            "node-opcua is missing: install nodejs and npm, then `. .ci/setup.sh; "
            "setup_node_peers` (bash .ci/test does both)"
        )
    assert app.settings.opcua is not None
    job = {
        "endpoint": app.settings.opcua.endpoint,
        "pki": str(pki),
        "namespace": NAMESPACE,
        "policy": "Basic256Sha256",
        "mode": "SignAndEncrypt",
        **job,
    }
    process = await asyncio.create_subprocess_exec(
        node,
        str(PEER / "client.js"),
        stdin=asyncio.subprocess.PIPE,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    assert process.stdin is not None
    assert process.stdout is not None
    process.stdin.write(json.dumps(job).encode())
    process.stdin.close()
    answers = []
    async with asyncio.timeout(30):
        async for line in process.stdout:
            if line.startswith(b"{"):
                answers.append(json.loads(line))
                if heard is not None:
                    await heard(answers[-1])
        await process.wait()
    assert process.stderr is not None
    assert answers, (await process.stderr.read()).decode()[-2000:]
    assert "fatal" not in answers[-1], answers[-1]["fatal"]
    return answers


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("node-opcua-pki")


@pytest.fixture
async def gateway(line: SimulatedLine, pki: Path) -> AsyncIterator[Application]:
    async with gateway_trusting_node_opcua(configuration(line), pki) as app:
        yield app


@contextlib.asynccontextmanager
async def gateway_trusting_node_opcua(
    config: GatewayConfig, pki: Path, **job: Any
) -> AsyncIterator[Application]:
    """The gateway, with node-opcua's certificate trusted the way an admin trusts one."""
    async with running_gateway(config) as app:
        assert app.settings.opcua is not None
        own = pki / "own" / "certs" / "client_certificate.pem"
        if not own.exists():  # node-opcua makes it on its first connection (refused)
            await node_client(app, pki, **job)
        for refused in app.settings.opcua.rejected_clients_dir.glob("*"):
            refused.unlink()
        trusted = app.settings.opcua.trusted_clients_dir
        shutil.copy(own, trusted / own.name)
        yield app


async def test_an_untrusted_client_is_refused_until_an_admin_trusts_it(
    gateway: Application, pki: Path
) -> None:
    assert gateway.settings.opcua is not None
    for kept in gateway.settings.opcua.trusted_clients_dir.glob("*"):
        kept.unlink()  # as on a gateway that never saw this client
    first = await node_client(gateway, pki, user=VIEWER, password=VIEWER_PASSWORD)
    assert first[0]["session"]["status"] == "BadCertificateUntrusted", first
    rejected = list(gateway.settings.opcua.rejected_clients_dir.iterdir())
    assert len(rejected) == 1
    rejected[0].rename(gateway.settings.opcua.trusted_clients_dir / rejected[0].name)
    again = await node_client(gateway, pki, user=VIEWER, password=VIEWER_PASSWORD)
    assert again[0]["session"]["status"] == "Good", again


async def test_browse_read_and_a_viewer_refused_a_write_and_a_call(
    gateway: Application, pki: Path
) -> None:
    await first_poll(gateway)
    answers = await node_client(
        gateway,
        pki,
        user=VIEWER,
        password=VIEWER_PASSWORD,
        mode="Sign",
        steps=[
            {"browse": "bus:line1"},
            {"read": "pump1.state"},
            {"read": "pump1.output_frequency_hz"},
            {"write": "pump1.set_frequency_hz", "value": 20.0},
            {"call": "pump1", "method": "pump1.RunForward"},
        ],
    )
    session, browse, state, frequency, write, call = answers
    assert session["session"]["status"] == "Good"
    assert set(browse["names"]) == {"pump1", "fan2"}
    assert (state["status"], state["value"], state["dataType"]) == ("Good", "stopped", "String")
    assert (frequency["status"], frequency["dataType"]) == ("Good", "Double")
    assert write["status"] == "BadUserAccessDenied"
    assert call["status"] == "BadUserAccessDenied"


async def test_an_operator_writes_calls_and_a_subscription_sees_the_drive_run(
    gateway: Application, line: SimulatedLine, pki: Path
) -> None:
    await first_poll(gateway)
    answers = await node_client(
        gateway,
        pki,
        user=OPERATOR,
        password=OPERATOR_PASSWORD,
        steps=[
            {"write": "pump1.set_frequency_hz", "value": 25.0},
            {"call": "pump1", "method": "pump1.RunForward"},
            {"subscribe": "pump1.state", "until": "running_forward", "timeout_ms": 5000},
            {"read": "pump1.set_frequency_hz"},
            {"call": "pump1", "method": "pump1.CoastStop"},
            {"read": "pump1.Parameters.P00.03"},
            {"write": "pump1.Parameters.P00.11", "value": 15.0},
            {"write": "pump1.Parameters.P00.11", "value": 4000.0},
        ],
    )
    _, write, run, seen, setpoint, stop, maximum, parameter, beyond = answers
    assert write["status"] == "Good"
    assert (run["status"], run["outputs"]) == ("Good", ["ok"])
    assert seen["status"] == "Good", seen
    assert setpoint["value"] == 25.0
    assert (stop["status"], stop["outputs"]) == ("Good", ["ok"])
    assert (maximum["status"], maximum["dataType"]) == ("Good", "Double")
    assert maximum["value"] == line.drives[1].parameter("P00.03") / 100
    assert parameter["status"] == "Good"
    assert line.drives[1].parameter("P00.11") == 150
    assert beyond["status"] == "BadOutOfRange"


async def test_run_reverse_with_a_frequency_argument(
    gateway: Application, line: SimulatedLine, pki: Path
) -> None:
    await first_poll(gateway)
    answers = await node_client(
        gateway,
        pki,
        user=OPERATOR,
        password=OPERATOR_PASSWORD,
        steps=[
            {"call": "pump1", "method": "pump1.RunReverse", "arguments": [30.0]},
            {"subscribe": "pump1.state", "until": "running_reverse", "timeout_ms": 5000},
            {"subscribe": "pump1.set_frequency_hz", "until": 30.0, "timeout_ms": 5000},
        ],
    )
    _, run, reverse, setpoint = answers
    assert (run["status"], run["outputs"]) == ("Good", ["ok"])
    assert reverse["status"] == "Good", reverse
    assert setpoint["status"] == "Good", setpoint


async def test_anonymous_is_not_offered_by_default(gateway: Application, pki: Path) -> None:
    """node-opcua reads the endpoint's user token policies and does not even try (asyncua's
    client does, and is refused: `test_opcua.py`)."""
    session = (await node_client(gateway, pki))[0]["session"]
    assert session["message"] == "Cannot find ANONYMOUS user token policy in end point description"


async def first_poll(app: Application) -> None:
    """Until the poller has read pump1 once."""
    for _ in range(100):
        if app.poller.telemetry("pump1").get("state"):
            return
        await asyncio.sleep(0.05)
    raise AssertionError("pump1 not polled within 5 s")


async def test_a_fault_is_an_event_on_the_drive_raised_then_cleared(
    gateway: Application, line: SimulatedLine, pki: Path
) -> None:
    """A SCADA's alarm list: events of the drive object, the fault's words and its severity."""
    await first_poll(gateway)

    async def trip_then_reset(said: dict[str, Any]) -> None:
        if said.get("listening"):
            line.inject_fault(1, 11)
        elif said.get("event", {}).get("Kind") == "fault_raised":
            line.clear_fault(1)

    answers = await node_client(
        gateway,
        pki,
        trip_then_reset,
        user=VIEWER,
        password=VIEWER_PASSWORD,
        steps=[{"events": "pump1", "count": 2, "timeout_ms": 10000}],
    )
    done = answers[-1]
    assert done["status"] == "Good", answers
    raised, cleared = done["events"]
    assert raised["Message"] == "fault raised: OL1: motor overload (code 11)"
    assert (raised["Severity"], raised["SourceName"]) == (800, "pump1")
    assert (raised["Kind"], raised["FaultCode"], raised["FaultName"]) == ("fault_raised", 11, "OL1")
    assert cleared["Message"] == "fault cleared: OL1: motor overload (code 11)"
    assert (cleared["Severity"], cleared["Kind"]) == (200, "fault_cleared")


@pytest.mark.parametrize("policy", ["Aes128_Sha256_RsaOaep", "Aes256_Sha256_RsaPss"])
@pytest.mark.parametrize("mode", ["Sign", "SignAndEncrypt"])
async def test_the_aes_policies_connect_node_opcua(
    line: SimulatedLine, pki: Path, policy: str, mode: str
) -> None:
    """OPC UA 1.04's policies, listed in `opcua.security`, as node-opcua asks for them."""
    config = configuration(line, security=[f"{policy}_{mode}"])
    job: dict[str, Any] = {"policy": policy, "mode": mode}
    async with gateway_trusting_node_opcua(config, pki, **job) as app:
        await first_poll(app)
        steps = [{"read": "pump1.state"}]
        answers = await node_client(
            app, pki, user=VIEWER, password=VIEWER_PASSWORD, steps=steps, **job
        )
        session, state = answers
        assert session["session"]["status"] == "Good", session
        assert (state["status"], state["value"]) == ("Good", "stopped"), state
