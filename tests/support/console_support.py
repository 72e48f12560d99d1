"""The gateway with its console on the simulated line, and an HTTP client that talks to it as a
browser or a script would (real sockets, aiohttp's client: an independent HTTP peer)."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

import aiohttp
import yaml

from gateway.app import Application
from gateway.config import GatewayConfig
from gateway.passwords import hash_password, hash_token
from gateway.profile.invt import STATE_WORD_1
from tests.support import TcpClient, present

OPERATOR_PASSWORD = "operator-secret-1"
VIEWER_PASSWORD = "viewer-secret-22"
OPERATOR_TOKEN = "operator-token-for-scripts-0123456789"
USERS = [
    {
        "name": "olga",
        "password_hash": hash_password(OPERATOR_PASSWORD),
        "role": "operator",
        "token_hash": hash_token(OPERATOR_TOKEN),
    },
    {"name": "victor", "password_hash": hash_password(VIEWER_PASSWORD), "role": "viewer"},
]
DRIVES = [
    {"name": "pump1", "address": 1, "model": "gd350"},
    {"name": "fan2", "address": 2, "model": "gd20"},
]


def console_config(port: str, *, anonymous_view: bool = False, **console: Any) -> GatewayConfig:
    """One bus on `port`, Modbus-TCP and the console on free loopback ports."""
    return GatewayConfig.model_validate(
        {
            "modbus_tcp": {"host": "127.0.0.1", "port": 0, **console.pop("modbus_tcp", {})},
            "buses": [
                {
                    "name": "line1",
                    "port": port,
                    "baudrate": 115200,
                    "parity": "E",
                    "timeout_ms": 100,
                    "retries": 1,
                    "offline_after": 2,
                }
            ],
            "drives": [{"bus": "line1", **d} for d in DRIVES],
            "console": {
                "enabled": True,
                "host": "127.0.0.1",
                "port": 0,
                "users": USERS,
                "anonymous_view": anonymous_view,
                **console,
            },
        }
    )


@dataclass
class ConsoleClient:
    """One browser-like client: its own cookie jar, and the CSRF token its login returned."""

    session: aiohttp.ClientSession
    base: str
    csrf: str | None = None

    async def login(self, name: str, password: str) -> aiohttp.ClientResponse:
        response = await self.session.post(
            f"{self.base}/api/login", json={"name": name, "password": password}
        )
        if response.status == 200:
            self.csrf = (await response.json())["csrf_token"]
        return response

    async def get_json(self, path: str) -> Any:
        async with self.session.get(f"{self.base}{path}") as response:
            assert response.status == 200, await response.text()
            return await response.json()

    async def post(
        self, path: str, body: dict[str, Any], *, csrf: bool = True, **headers: str
    ) -> tuple[int, Any]:
        sent = dict(headers)
        if csrf and self.csrf is not None:
            sent["X-CSRF-Token"] = self.csrf
        async with self.session.post(f"{self.base}{path}", json=body, headers=sent) as response:
            return response.status, await response.json()


@contextlib.asynccontextmanager
async def console_client(app: Application) -> AsyncIterator[ConsoleClient]:
    # unsafe=True: the cookie jar keeps cookies of an IP address host (127.0.0.1), as browsers do.
    jar = aiohttp.CookieJar(unsafe=True)
    async with aiohttp.ClientSession(cookie_jar=jar) as session:
        yield ConsoleClient(session, f"http://127.0.0.1:{present(app.console).port}")


async def state_word(app: Application, unit_id: int) -> int:
    """What the drive itself says (state word 1), read by a Modbus-TCP client, not the console."""
    client = await TcpClient.connect(app.tcp.port)
    try:
        return (await client.read(unit_id, STATE_WORD_1))[0]
    finally:
        await client.close()


BASE = {"buses": [{"name": "line1", "port": "/dev/ttyUSB0"}]}


def config_with(console: dict[str, object]) -> str:
    """A file of one bus and this `console:` section, as YAML."""
    return yaml.safe_dump({**BASE, "console": console})
