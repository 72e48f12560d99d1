"""The console shows each bus's and drive's share of the line: what its polls were planned to
take (the figure `check-config` prints for the same file) beside what it took lately, SCADA's
requests included. Through the JSON API, and in a real Chromium as a person reads the overview.

The line is slow (9600 baud, the simulator's wire time emulated) so a drive's polls take a share
worth reading: some 8 % each.
"""

from __future__ import annotations

import asyncio
import re
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.app import Application
from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, eventually, present, running_gateway
from tests.support.browser import CHROMEDRIVER, CHROMIUM, Browser, showing
from tests.support.console_support import VIEWER_PASSWORD, console_client, console_config
from tests.support.processes import run_cli

pytestmark = pytest.mark.line(
    addresses=(1, 2), models={1: "gd350", 2: "gd20"}, baudrate=9600, response_delay_ms=1.0
)
SETTLE_S = 6.0
"""Long enough for the measured share's 5 s window to hold polls only."""


def slow_line_config(port: str, **console: Any) -> GatewayConfig:
    config = console_config(port, **console)
    bus = config.buses[0].model_copy(update={"baudrate": 9600, "timeout_ms": 300})
    return config.model_copy(update={"buses": (bus,)})


def check_config_shares(config: GatewayConfig, tmp_path: Path) -> dict[str, float]:
    """`check-config`'s planned share of the bus and of each drive, in percent, as it prints
    them for the same configuration written to a file."""
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump(config.model_dump(mode="json", exclude_none=True)))
    result = run_cli("check-config", "--config", str(path))
    assert result.returncode == 0, result.stderr
    shares = {
        match[1]: float(match[2])
        for match in re.finditer(r"^ {4}(\w+): [\d.]+ requests/s, ([\d.]+)%$", result.stdout, re.M)
    }
    bus = re.search(
        r"^  line1: 2 polled, [\d.]+ requests/s, ([\d.]+)% of the line$", result.stdout, re.M
    )
    assert bus is not None, result.stdout
    return {"line1": float(bus[1]), **shares}


@pytest.fixture
async def gateway(line: SimulatedLine) -> AsyncIterator[Application]:
    async with running_gateway(slow_line_config(line.path, anonymous_view=True)) as app:
        yield app


async def test_planned_shares_are_check_configs_and_polls_alone_take_about_that(
    line: SimulatedLine, gateway: Application, tmp_path: Path
) -> None:
    printed = check_config_shares(slow_line_config(line.path), tmp_path)
    async with console_client(gateway) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        await asyncio.sleep(SETTLE_S)
        overview = await web.get_json("/api/overview")
        bus = overview["buses"][0]
        drives = {d["name"]: d for d in overview["drives"]}
        assert round(bus["planned_utilisation"] * 100, 1) == pytest.approx(
            printed["line1"], abs=0.1
        )
        assert bus["over_budget"] is False  # 17 %: room left for SCADA
        for name in ("pump1", "fan2"):
            planned = drives[name]["planned_utilisation"]
            assert round(planned * 100, 1) == pytest.approx(printed[name], abs=0.1)
            assert 0.05 < planned < 0.12  # the two poll groups of an INVT drive at 9600 baud

        seen: list[dict[str, Any]] = []

        async def polls_alone_take_their_plan() -> bool:
            # Polls alone: the measured share is an exchange's time from its request's first
            # byte to its reply's last (the drive's 1 ms answer delay in it), the planned one
            # the frames and the silence before and after each (a quarter of it at 9600 baud,
            # for 3 words). A timeout on a loaded box holds the line 300 ms: that window is
            # not polls alone, the next one is asked for.
            overview = await web.get_json("/api/overview")
            seen.append(overview)
            drives = overview["drives"]
            bus = overview["buses"][0]["utilisation"]
            return all(
                d["planned_utilisation"] * 0.7 <= d["utilisation"] <= d["planned_utilisation"] * 1.6
                for d in drives
            ) and bus == pytest.approx(sum(d["utilisation"] for d in drives), abs=0.002)

        try:
            await eventually(polls_alone_take_their_plan, within_s=3 * SETTLE_S, every_s=0.5)
        except AssertionError:
            pytest.fail(f"last seen: {seen[-1]['buses']} {seen[-1]['drives']}")


async def test_scada_reads_show_as_a_drives_share_above_its_planned_one(
    gateway: Application,
) -> None:
    client = await TcpClient.connect(gateway.tcp.port)
    try:
        async with console_client(gateway) as web:
            assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
            await asyncio.sleep(SETTLE_S)  # past the start's reads

            async def fan_busy() -> bool:
                # SCADA reads fan2's 12 running values back to back.
                await client.request(2, bytes.fromhex("03 3000 000C"))
                drives = (await web.get_json("/api/overview"))["drives"]
                fan, pump = (next(d for d in drives if d["name"] == n) for n in ("fan2", "pump1"))
                # fan2's share beyond its polls' plan; pump1's its polls' still.
                return bool(
                    fan["utilisation"] > 3 * fan["planned_utilisation"]
                    and pump["utilisation"] <= pump["planned_utilisation"] * 1.6
                )

            await eventually(fan_busy, within_s=SETTLE_S * 2, every_s=0.0)
    finally:
        await client.close()


@pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="Debian's chromium and chromium-driver are installed by .ci/test",
)
async def test_the_overview_shows_each_share_beside_the_planned_one(
    gateway: Application,
) -> None:
    browser = await asyncio.to_thread(Browser, f"http://127.0.0.1:{present(gateway.console).port}")
    try:
        await browser.open("/")
        await browser.wait(showing("#drives tr[data-drive=fan2] td.online", "online"))
        await eventually(lambda: gateway.poller.polls > 10, within_s=SETTLE_S)
        await asyncio.sleep(SETTLE_S)  # the measured share's window holds polls only
        # The page's figures are the API's, as a person reads them on the overview.
        async with console_client(gateway) as web:
            overview = await web.get_json("/api/overview")
        planned = f"{overview['buses'][0]['planned_utilisation'] * 100:.1f} %"
        await browser.wait(showing("#buses tr[data-bus=line1] td.planned", planned))
        for drive in overview["drives"]:
            cell = f"#drives tr[data-drive={drive['name']}] td.line"
            share = f"(planned {drive['planned_utilisation'] * 100:.1f} %)"
            await browser.wait(showing(cell, share))
            shown = await browser.text(cell)
            measured = float(shown.split(" %")[0])
            assert drive["planned_utilisation"] * 70 <= measured, shown  # the polls' frames
        await browser.screenshot("overview-line-share")
    finally:
        await asyncio.to_thread(browser.close)
