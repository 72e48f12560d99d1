"""The console in a real browser: Debian's Chromium, driven by Selenium through chromium-driver,
against the gateway on the simulated line. What a person sees and clicks, checked as they would.

A screenshot of each page is saved under `test-artifacts/console/` (or $INVT_GATEWAY_ARTIFACTS).
Selenium's calls block, so they run in a thread while the gateway serves on this event loop.
"""

from __future__ import annotations

import asyncio
import re
import shutil
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from selenium.common.exceptions import StaleElementReferenceException
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select

from gateway.app import Application
from gateway.instruments.simulator import SimulatedLine
from gateway.profile import get_profile
from tests.support import TcpClient, present, running_gateway, write_pdu
from tests.support.browser import CHROMEDRIVER, CHROMIUM, Browser, answered, showing
from tests.support.console_support import (
    OPERATOR_PASSWORD,
    VIEWER_PASSWORD,
    console_config,
    state_word,
)

STATE_WORD_1 = 0x2100
RUNNING_FORWARD = 1
STOPPED = 3

pytestmark = pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="Debian's chromium and chromium-driver are installed by .ci/test",
)


@pytest.fixture
async def console(line: SimulatedLine) -> AsyncIterator[tuple[Application, Browser]]:
    async with running_gateway(console_config(line.path, anonymous_view=True)) as app:
        browser = await asyncio.to_thread(Browser, f"http://127.0.0.1:{present(app.console).port}")
        try:
            yield app, browser
        finally:
            await asyncio.to_thread(browser.close)


async def test_overview_lists_drives_live_and_shows_a_modbus_tcp_write_within_2_s(
    console: tuple[Application, Browser],
) -> None:
    app, browser = console
    await browser.open("/")
    await browser.wait(showing("#drives tr[data-drive=pump1] td.state", "stopped"))
    await browser.wait(showing("#drives tr[data-drive=fan2] td.online", "online"))
    assert "line1" in await browser.text("#buses tbody")
    # Another SCADA client starts pump1 at 30 Hz: the page shows it without a reload.
    client = await TcpClient.connect(app.tcp.port)
    await client.request(1, bytes.fromhex("10 2000 0002 04 0001 0BB8"))
    await client.close()
    await browser.wait(showing("#drives tr[data-drive=pump1] td.state", "running forward"), 2.0)
    await browser.wait(lambda d: "0.00" not in _cell(d, "pump1", "frequency"), 5.0)
    await browser.screenshot("overview")


def _cell(driver: Any, drive: str, cell: str) -> str:
    selector = f"#drives tr[data-drive={drive}] td.{cell}"
    return str(driver.find_element(By.CSS_SELECTOR, selector).text)


async def test_an_operator_starts_a_drive_from_its_page_and_it_runs(
    console: tuple[Application, Browser],
) -> None:
    app, browser = console
    await browser.login("olga", OPERATOR_PASSWORD)
    await browser.wait(showing("#who", "olga (operator)"))
    await browser.open("/drives/pump1")
    await browser.wait(showing("#values", "stopped"))
    await browser.type("#setpoint", "25")
    await browser.click("#setpoint-form button[type=submit]")
    await browser.wait(showing("#confirm-text", "25.00 Hz"))
    await browser.click("#confirm-ok")
    await browser.wait(showing("#toast", "done"))
    await browser.click("button[data-command=run_forward]")
    await browser.wait(showing("#confirm-text", "Run forward pump1?"))
    await browser.click("#confirm-ok")
    await browser.wait(showing("#toast", "Run forward pump1: done"))
    assert await state_word(app, 1) == RUNNING_FORWARD
    await browser.wait(showing("#values tr[data-key=state]", "running forward"), 2.0)
    await browser.wait(showing("#drive-events", "control word = 1 (run_forward)"), 12.0)
    await browser.screenshot("drive")


async def test_a_viewers_write_is_refused_403_and_the_drive_unchanged(
    console: tuple[Application, Browser],
) -> None:
    app, browser = console
    await browser.login("victor", VIEWER_PASSWORD)
    await browser.wait(showing("#who", "victor (viewer)"))
    await browser.open("/drives/pump1")
    await browser.wait(showing("#controls-note", "Log in as an operator"))
    # The buttons are disabled for a viewer; what the page's own code would send is refused.
    status = await browser.run(
        browser.driver.execute_async_script,
        """const done = arguments[arguments.length - 1];
        const session = await (await fetch('/api/session')).json();
        const response = await fetch('/api/drives/pump1/command', {method: 'POST',
          headers: {'Content-Type': 'application/json', 'X-CSRF-Token': session.csrf_token},
          body: JSON.stringify({command: 'run_forward'})});
        done(response.status);""",
    )
    assert status == 403
    assert await state_word(app, 1) == STOPPED


async def test_a_wrong_password_is_refused_then_rate_limited(
    console: tuple[Application, Browser],
) -> None:
    _, browser = console
    await browser.login("olga", "wrong-password")
    await browser.wait(showing("#login-error", "wrong name or password"))
    await browser.screenshot("login")
    # A person trying again and again, each try answered before the next: clicks sent all at
    # once would race, and the page shows whichever answer came last.
    for _ in range(8):
        await browser.click("#login-submit")  # the page clears the error as it submits
        answer = await browser.wait(answered("#login-error"), 10.0)
        if "too many failed logins" in answer:
            break
    else:
        raise AssertionError(f"8 wrong passwords and still {answer!r}")
    await browser.type("#login-password", OPERATOR_PASSWORD)
    await browser.click("#login-submit")
    await browser.wait(showing("#login-error", "too many failed logins"))


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is installed by .ci/test")
async def test_the_monitor_shows_an_mbpoll_read_decoded_within_1_s(
    console: tuple[Application, Browser],
) -> None:
    app, browser = console
    await browser.open("/monitor/line1")
    await browser.wait(showing("#live", "live"))
    await browser.wait(showing("#traffic tbody", "poll"))  # the stream is on
    process = await asyncio.create_subprocess_exec(
        *("mbpoll", "-m", "tcp", "-p", str(app.tcp.port), "-0", "-1"),
        *("-a", "1", "-r", "8448", "127.0.0.1"),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
    )
    out, _ = await asyncio.wait_for(process.communicate(), 20)
    assert "[8448]: \t3" in out.decode()
    # mbpoll has answered: within a second the page shows its read, in words.
    row = "#traffic tbody tr"
    await browser.wait(showing(row, "read 2100H state word 1 → 0003H stopped"), 1.0)
    assert "tcp:127.0.0.1" in await browser.text("#traffic tbody")
    await browser.click("#f-hex")
    await browser.wait(showing("#traffic tbody .hex", "01 03 21 00 00 01"))
    await browser.screenshot("monitor")


async def test_a_dead_drive_turns_offline_and_its_timeouts_show_in_the_monitor(
    console: tuple[Application, Browser], line: SimulatedLine
) -> None:
    _, browser = console
    await browser.open("/monitor/line1")
    await browser.wait(showing("#traffic tbody", "fan2"))
    line.set_dead(2)

    def fan2_timed_out(driver: Any) -> bool:
        # fan2's row, not merely the first bad one: on a busy box pump1 may time out too.
        try:
            rows = driver.find_elements(By.CSS_SELECTOR, "#traffic tbody tr.bad")
            return any("fan2" in row.text and "timeout" in row.text for row in rows)
        except StaleElementReferenceException:  # the monitor replaced the row meanwhile
            return False

    await browser.wait(fan2_timed_out, 10.0)
    await browser.screenshot("monitor-dead-drive")
    await browser.open("/")
    await browser.wait(showing("#drives tr[data-drive=fan2] td.online", "offline"), 10.0)
    await browser.wait(showing("#events", "drive offline"), 10.0)
    await browser.screenshot("overview-dead-drive")


async def test_the_monitor_filters_pauses_and_downloads_what_it_shows(
    console: tuple[Application, Browser], tmp_path: Path
) -> None:
    _, browser = console
    await browser.run(
        browser.driver.execute_cdp_cmd,
        "Page.setDownloadBehavior",
        {"behavior": "allow", "downloadPath": str(tmp_path)},
    )
    await browser.open("/monitor/line1")
    await browser.wait(showing("#traffic tbody", "fan2"))
    await browser.run(
        lambda: Select(browser.driver.find_element(By.ID, "f-drive")).select_by_value("pump1")
    )
    await browser.wait(lambda d: "fan2" not in d.find_element(By.ID, "traffic").text)
    await browser.click("#pause")
    await browser.wait(showing("#count", "paused"))
    rows = await browser.text("#traffic tbody")
    # The line goes on (polls every half second): a paused page holds them back, and says so.
    await browser.wait(lambda d: "paused (0 waiting)" not in d.find_element(By.ID, "count").text)
    assert await browser.text("#traffic tbody") == rows
    await browser.click("#download-csv")
    csv_file = tmp_path / "traffic-line1.csv"
    await browser.wait(lambda _: csv_file.exists() and csv_file.stat().st_size > 0)
    lines = csv_file.read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith("time,client,unit_id,address,drive,function,meaning,outcome")
    assert len(lines) > 1
    assert all('"pump1"' in line for line in lines[1:])


SIZES = {"phone": (390, 844), "tablet": (768, 1024), "desktop": (1400, 1000)}
PAGES = {
    "overview": ("/", "#drives tr[data-drive=pump1]"),
    "drive": ("/drives/pump1", "#values tr[data-key=state]"),
    "monitor": ("/monitor/line1", "#traffic tbody tr[data-seq]"),
    "events": ("/events", "#all-events tbody tr"),
    "diagnostics": ("/diagnostics", "table.diagnostics tbody tr[data-drive=fan2]"),
    "login": ("/login", "#login-form"),
}
FITS = """
const header = document.querySelector("header .user a, header .user button");
const box = header.getBoundingClientRect();
return {
  page: document.documentElement.scrollWidth, window: window.innerWidth,
  login: [box.left, box.right, box.top, box.bottom, header.offsetParent !== null],
};"""


async def test_every_page_fits_a_phone_a_tablet_and_a_desktop_without_scrolling_sideways(
    console: tuple[Application, Browser],
) -> None:
    _, browser = console
    for size, (width, height) in SIZES.items():
        await browser.resize(width, height)
        for page, (path, filled) in PAGES.items():
            await browser.open(path)
            await browser.wait(showing(filled, ""))
            fits = await browser.run(browser.driver.execute_script, FITS)
            assert fits["window"] == width
            assert fits["page"] <= width, f"{page} at {size}: {fits['page']} px wide"
            left, right, top, bottom, shown = fits["login"]
            where = f"{page} at {size}: the header's login at {fits['login']}"
            assert shown, where
            assert left >= 0, where
            assert right <= width, where
            assert top >= 0, where
            assert bottom <= height, where
            await browser.screenshot(f"{page}-{size}")
        if size == "phone":  # the drive page's charts, for a person to look at
            await browser.open("/drives/pump1")
            await browser.wait(lambda d: d.find_elements(By.CSS_SELECTOR, ".chart canvas"))
            scroll = "document.querySelector('.charts').scrollIntoView()"
            await browser.run(browser.driver.execute_script, scroll)
            await browser.screenshot("drive-charts-phone")


CHART_WIDTH = """const box = document.querySelector('#chart-frequency');
const chart = box.querySelector('.uplot');
return [chart === null ? 0 : chart.offsetWidth, box.clientWidth];"""


def chart_fills_its_box(driver: Any) -> bool:
    chart, box = driver.execute_script(CHART_WIDTH)
    return bool(chart) and abs(chart - box) <= 2


async def test_a_chart_follows_the_window_when_it_is_resized(
    console: tuple[Application, Browser],
) -> None:
    _, browser = console
    await browser.resize(1400, 1000)
    await browser.open("/drives/pump1")
    await browser.wait(chart_fills_its_box)
    widths = []
    for window in (700, 390, 1100):
        await browser.resize(window, 900)
        await browser.wait(chart_fills_its_box)
        chart, _ = await browser.run(browser.driver.execute_script, CHART_WIDTH)
        assert chart < window
        widths.append(chart)
    assert len(set(widths)) == len(widths)  # one chart a row at 700 px, three at 1100


async def test_the_events_page_filters_by_kind_and_downloads_what_it_shows(
    console: tuple[Application, Browser], tmp_path: Path
) -> None:
    _, browser = console
    await browser.run(
        browser.driver.execute_cdp_cmd,
        "Page.setDownloadBehavior",
        {"behavior": "allow", "downloadPath": str(tmp_path)},
    )
    await browser.login("olga", OPERATOR_PASSWORD)
    await browser.wait(showing("#who", "olga (operator)"))
    await browser.open("/events")
    await browser.run(
        lambda: Select(browser.driver.find_element(By.ID, "e-kind")).select_by_value("login")
    )
    await browser.wait(showing("#all-events tbody", "olga logged in from 127.0.0.1"))
    assert "kind=login" in await browser.run(lambda: browser.driver.current_url)
    when = await browser.text("#all-events tbody tr td.time")
    assert re.fullmatch(r"\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2}", when), when
    assert "olga from 127.0.0.1" in await browser.text("#all-events tbody tr")
    await browser.screenshot("events")
    await browser.type("#e-until", "2000-01-01 00:00\n")  # before anything happened here
    await browser.wait(showing("#all-events tbody", "no event matches"))
    await browser.type("#e-until", "yesterday\n")
    await browser.wait(showing("#live", "a time as 2026-11-25 06:00"))
    await browser.type("#e-until", "\n")
    await browser.wait(showing("#all-events tbody", "olga logged in"))
    await browser.click("#e-csv")
    csv_file = tmp_path / "events.csv"
    await browser.wait(lambda _: csv_file.exists() and csv_file.stat().st_size > 0)
    lines = csv_file.read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith("id,time,kind,type,drive,bus,text,who,user,address")
    assert len(lines) == 2
    assert ",login," in lines[1]


async def test_the_parameter_browser_shows_every_group_ranges_defaults_and_finds_a_parameter(
    console: tuple[Application, Browser],
) -> None:
    """A technician on pump1's page: every group of its series as a tab, the manual's words for
    a choice, the range with its unit, the default, and P00.03 found by its wire address once
    a SCADA write has moved it off the factory's value."""
    app, browser = console
    await browser.open("/drives/pump1")
    await browser.wait(showing("#parameters tbody", "P00.03"))
    tabs = await browser.run(
        lambda: [b.text for b in browser.driver.find_elements(By.CSS_SELECTOR, "#groups button")]
    )
    groups = sorted({row.group for row in get_profile("gd350").parameters})
    assert tabs == [*groups, "2000H", "2100H", "3000H"]
    top = "#parameters tr[data-name='P00.03']"
    assert "0.00 ... 630.00 Hz, at least P00.04" in await browser.text(top)
    assert "≠ default" not in await browser.text(top)
    await browser.click("#groups button[data-group=P05]")
    await browser.wait(showing("#parameters tr[data-name='P05.01']", "1 (forward rotation)"))

    client = await TcpClient.connect(app.tcp.port)
    try:
        assert await client.request(1, write_pdu(0x0003, 6000)) == write_pdu(0x0003, 6000)
    finally:
        await client.close()
    await browser.type("#parameter-find-text", "0003H")
    await browser.click("#parameter-find-go")
    await browser.wait(showing("#parameter-found", "1 found"))
    await browser.wait(showing(top, "≠ default"))
    shown = await browser.text(top)
    assert "60.00 Hz" in shown
    assert "50.00 Hz" in shown  # the default beside it
    assert "differs" in str(
        await browser.run(
            lambda: browser.driver.find_element(By.CSS_SELECTOR, top).get_attribute("class")
        )
    )
    await browser.type("#parameter-find-text", "acc time")
    await browser.click("#parameter-find-go")
    await browser.wait(showing("#parameters tr[data-name='P00.11']", "depends on model"))
    assert "0.0 ... 3600.0 s" in await browser.text("#parameters tr[data-name='P00.11']")
    await browser.run(
        browser.driver.execute_script,
        "document.getElementById('parameter-find').scrollIntoView()",
    )
    await browser.screenshot("parameters")


DIALOG_FIELDS = """return [...document.querySelectorAll('#confirm label')]
  .filter((label) => label.offsetParent !== null).map((label) => label.id);"""


async def test_every_confirmation_dialog_shows_only_its_own_fields(
    console: tuple[Application, Browser],
) -> None:
    """A command asks "Run forward pump1?" and nothing else: no RAM-only box, no empty Value
    field. A parameter write asks for its value (and RAM only, for a P parameter)."""
    _, browser = console
    await browser.login("olga", OPERATOR_PASSWORD)
    await browser.wait(showing("#who", "olga (operator)"))
    await browser.open("/drives/pump1")
    await browser.wait(showing("#controls-note", "every command asks for a confirmation"))
    await browser.type("#setpoint", "25")
    openers = {
        "run forward": "button[data-command=run_forward]",
        "run reverse": "button[data-command=run_reverse]",
        "stop": "button[data-command=stop]",
        "coast stop": "button[data-command=coast_stop]",
        "fault reset": "button[data-command=fault_reset]",
        "set-point": "#setpoint-form button[type=submit]",
    }
    for command, opener in openers.items():
        await browser.click(opener)
        await browser.wait(lambda d: d.find_element(By.ID, "confirm").is_displayed())
        shown = await browser.run(browser.driver.execute_script, DIALOG_FIELDS)
        assert shown == [], f"{command}'s dialog shows {shown}"
        await browser.click("#confirm button[value=cancel]")
        await browser.wait(lambda d: not d.find_element(By.ID, "confirm").is_displayed())
    await browser.wait(showing("#parameters tr[data-name='P00.03']", "Write"))
    await browser.click("#parameters tr[data-name='P00.03'] button")
    await browser.wait(lambda d: d.find_element(By.ID, "confirm").is_displayed())
    shown = await browser.run(browser.driver.execute_script, DIALOG_FIELDS)
    assert shown == ["confirm-ram-label", "confirm-value-label"]
    await browser.screenshot("confirm-parameter")
    await browser.click("#confirm button[value=cancel]")


async def test_a_refused_set_point_names_the_drives_maximum_and_an_error_says_its_write_once(
    console: tuple[Application, Browser],
) -> None:
    """pump1's P00.03 is 50.00 Hz: the drive refuses 60 Hz with a bare 04H, and the page says
    which limit it hit. A value outside a parameter's range is said once, not twice."""
    _, browser = console
    await browser.login("olga", OPERATOR_PASSWORD)
    await browser.wait(showing("#who", "olga (operator)"))
    await browser.open("/drives/pump1")
    await browser.wait(showing("#controls-note", "every command asks for a confirmation"))
    await browser.type("#setpoint", "60")
    await browser.click("#setpoint-form button[type=submit]")
    await browser.wait(showing("#confirm-text", "60.00 Hz"))
    await browser.click("#confirm-ok")
    await browser.wait(showing("#toast", "drive refused"))
    said = await browser.text("#toast")
    assert "60.00 Hz is above P00.03 = 50.00 Hz, the drive's maximum" in said, said
    await browser.screenshot("setpoint-refused")

    await browser.wait(showing("#parameters tr[data-name='P00.11']", "Write"))
    await browser.click("#parameters tr[data-name='P00.11'] button")
    await browser.type("#confirm-value", "99999")
    await browser.click("#confirm-ok")
    await browser.wait(showing("#toast", "is outside"))
    said = await browser.text("#toast")
    assert said.startswith("P00.11 = 99999 is outside"), said
    assert said.count("99999") == 1, said


MONITOR_PAGE = """const seqs = [...document.querySelectorAll('#traffic tbody tr[data-seq]')]
  .map((row) => Number(row.dataset.seq));
return {seqs, height: document.documentElement.scrollHeight};"""


def more_rows_than(count: int) -> Any:
    def check(driver: Any) -> bool:
        shown = driver.find_element(By.ID, "count").text.split(" shown")[0]
        return shown.isdigit() and int(shown) > count

    return check


async def test_the_monitor_pages_its_rows_on_a_phone(
    console: tuple[Application, Browser],
) -> None:
    """On a phone a row is a card: 50 of them a page, older ones a click away, not 2,000
    cards in one page tens of thousands of pixels tall."""
    _, browser = console
    await browser.resize(390, 844)
    await browser.open("/monitor/line1")
    await browser.wait(more_rows_than(60), 40.0)
    await browser.click("#pause")  # the rows stand still while they are counted
    await browser.wait(showing("#count", "paused"))
    newest = await browser.run(browser.driver.execute_script, MONITOR_PAGE)
    assert len(newest["seqs"]) == 50
    assert newest["height"] < 50 * 200, f"{newest['height']} px tall"
    assert newest["seqs"] == sorted(newest["seqs"], reverse=True)
    assert "rows 1 to 50 of" in await browser.text("#page-place")
    await browser.click("#page-older")
    await browser.wait(showing("#page-place", "rows 51 to"))
    older = await browser.run(browser.driver.execute_script, MONITOR_PAGE)
    assert older["seqs"]
    assert max(older["seqs"]) < min(newest["seqs"])
    await browser.screenshot("monitor-phone-older")
    await browser.click("#page-newer")
    await browser.wait(showing("#page-place", "rows 1 to 50 of"))
    again = await browser.run(browser.driver.execute_script, MONITOR_PAGE)
    assert again["seqs"] == newest["seqs"]
