"""What anyone can send the console before logging in: each answered with one clear status
(414, 413, 400), counted, and logged once a minute in aggregate, never a traceback. Against a
real `invt-gateway run` on the simulated line (its own log, aggregated as a service's is)."""

from __future__ import annotations

import asyncio
import io
import json
from pathlib import Path

from gateway.instruments.simulator import SimulatedLine
from tests.support import free_port
from tests.support.console_support import ConsoleClient
from tests.support.http import http_get
from tests.support.processes import GatewayProcess, gateway_process
from tests.system.test_console_config_edit import ADMIN_PASSWORD, browser_like, config

LONG_URL = b"GET /api/overview?" + b"a" * 9000 + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
HALF_A_BODY = (
    b"POST /api/login HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
    b'Content-Length: 60\r\n\r\n{"name": "victor", "pass'
)


async def answer_to(port: int, sent: bytes) -> bytes:
    """What the console answers `sent` with, up to its closing the connection."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(sent)
    try:
        return await asyncio.wait_for(reader.read(), 10)
    finally:
        writer.close()


def new_lines(gateway: GatewayProcess, since: int) -> list[str]:
    return gateway.log.lines[since:]


async def test_bad_requests_are_answered_counted_and_logged_in_aggregate(
    line: SimulatedLine, tmp_path: Path
) -> None:
    port, metrics_port = free_port(), free_port()
    with gateway_process(started_config(line, port, metrics_port), tmp_path) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        before = len(gateway.log.lines)

        # 300 requests with a 9 kB URL, nobody logged in: 414 each.
        for _ in range(300):
            answer = await answer_to(port, LONG_URL)
            assert answer.startswith(b"HTTP/1.1 414 "), answer[:100]
        assert b'"error": "the request line is over 8190 bytes"' in answer

        # Bodies the deadline (1 s) closes: the connection goes, the log says so once.
        for _ in range(5):
            assert await answer_to(port, HALF_A_BODY) == b""

        async with browser_like(port) as web:
            # A body over the limit: 413, whether its length is announced or not.
            big = json.dumps({"name": "x" * 20_000, "password": "y"}).encode()
            for body in (big, io.BytesIO(big)):
                async with web.session.post(
                    f"{web.base}/api/login", data=body, headers=JSON
                ) as response:
                    assert response.status == 413
                    assert (await response.json())["error"] == "the body is over 16 kB"
            # 50,000 nested [ in a Check: 400, in the body or in the text checked.
            assert (await web.login("ada", ADMIN_PASSWORD)).status == 200
            deep = "[" * 50_000
            async with web.session.post(
                f"{web.base}/api/config/check", data=deep, headers=csrf(web)
            ) as response:
                assert response.status == 400
                assert (await response.json())["error"] == "the body is nested too deeply"
            status, checked = await web.post("/api/config/check", {"text": deep})
            assert status in (200, 400), checked
            assert checked["ok"] is False
            assert "nested too deeply" in json.dumps(checked)

        said = new_lines(gateway, before)
        assert not [line for line in said if "Traceback" in line or "ERROR" in line], said
        assert len(said) <= 6, said  # login and check lines, one per kind of refusal
        _, _, text = await http_get(metrics_port, "/metrics")
        assert 'invt_gateway_console_bad_requests_total{status="414"} 300.0' in text
        assert 'invt_gateway_console_bad_requests_total{status="413"} 2.0' in text
        assert 'invt_gateway_console_request_timeouts_total{phase="body"} 5.0' in text


JSON = {"Content-Type": "application/json"}


def csrf(web: ConsoleClient) -> dict[str, str]:
    assert web.csrf is not None
    return {**JSON, "X-CSRF-Token": web.csrf}


def started_config(line: SimulatedLine, port: int, metrics_port: int) -> dict[str, object]:
    written = config(line, port)
    written["console"]["request_timeout_s"] = 1
    written["metrics"] = {"enabled": True, "host": "127.0.0.1", "port": metrics_port}
    return written
