"""The history page, the configuration page and the tables' layout in a real Chromium (Debian's,
through Selenium, as `test_console_browser`), against the gateway on the simulated line.

Screenshots go to `test-artifacts/console/` beside the other pages'.
"""

from __future__ import annotations

import asyncio
import re
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import pytest
import yaml
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.support import expected_conditions

from gateway.app import Application
from gateway.commands.run import Reloader, _edit_from_console
from gateway.config import load_config
from gateway.instruments.simulator import SimulatedLine
from gateway.passwords import hash_password
from gateway.poller.drive_state import iso_time
from gateway.settings import runtime_settings
from gateway.systemd import Notifier
from tests.support import present as configured
from tests.support import running_application
from tests.support.browser import CHROMEDRIVER, CHROMIUM, Browser, showing
from tests.support.console_support import OPERATOR_PASSWORD, console_config
from tests.system.test_console_browser import FITS, SIZES

ADMIN_PASSWORD = "admin-secret-333"

pytestmark = pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="Debian's chromium and chromium-driver are installed by .ci/test",
)


@pytest.fixture
async def console(
    line: SimulatedLine, tmp_path: Path
) -> AsyncIterator[tuple[Application, Browser]]:
    """The gateway as `invt-gateway run --config FILE` wires it (the file editable from the
    console by its admin), with anonymous viewing on."""
    data = console_config(line.path, anonymous_view=True).model_dump(
        mode="json", exclude_unset=True
    )
    admin = {"name": "ada", "password_hash": hash_password(ADMIN_PASSWORD), "role": "admin"}
    data["console"]["users"].append(admin)
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    app = Application(runtime_settings(load_config(path)))
    _edit_from_console(app, str(path), Reloader(app, str(path), Notifier(None)))
    async with running_application(app):
        browser = await asyncio.to_thread(
            Browser, f"http://127.0.0.1:{configured(app.console).port}"
        )
        try:
            yield app, browser
        finally:
            await asyncio.to_thread(browser.close)


async def downloads_to(browser: Browser, directory: Path) -> None:
    await browser.run(
        browser.driver.execute_cdp_cmd,
        "Page.setDownloadBehavior",
        {"behavior": "allow", "downloadPath": str(directory)},
    )


async def attribute(browser: Browser, selector: str, name: str) -> str:
    found = await browser.run(
        lambda: browser.driver.find_element(By.CSS_SELECTOR, selector).get_attribute(name)
    )
    return str(found or "")


def present(selector: str) -> Callable[[Any], bool]:
    return lambda driver: bool(driver.find_elements(By.CSS_SELECTOR, selector))


def charts(driver: Any) -> list[str]:
    found = driver.find_elements(By.CSS_SELECTOR, "#h-charts .chart")
    return [c.get_attribute("data-key") for c in found if c.find_elements(By.TAG_NAME, "canvas")]


async def test_any_value_is_charted_zoomed_and_downloaded(
    console: tuple[Application, Browser], tmp_path: Path
) -> None:
    _, browser = console
    await downloads_to(browser, tmp_path)
    await browser.open("/history?drive=pump1&window=15m")
    await browser.wait(lambda d: charts(d) == ["output_frequency_hz", "output_current_a"])
    await browser.wait(showing("#h-count", "one per 1 s"))
    # Any polled value: the bus voltage added by a click, kept in the address.
    await browser.click("#h-keys input[value=bus_voltage_v]")
    await browser.wait(lambda d: "bus_voltage_v" in charts(d))
    address = urlsplit(await browser.run(lambda: browser.driver.current_url))
    keys = parse_qs(address.query)["keys"][0].split(",")
    assert sorted(keys) == ["bus_voltage_v", "output_current_a", "output_frequency_hz"]
    await browser.screenshot("history")
    # Dragging across a chart zooms every chart into that stretch; the CSV holds that stretch.
    await asyncio.sleep(3)  # a few seconds of points to zoom into
    await browser.open("/history?drive=pump1&window=15m")
    await browser.wait(lambda d: len(charts(d)) == 2)

    def drag() -> None:
        over = browser.driver.find_element(By.CSS_SELECTOR, "#h-charts .chart .u-over")
        width = over.size["width"]
        chain = ActionChains(browser.driver)  # offsets from the element's centre
        chain.move_to_element_with_offset(over, -width // 4, 0).click_and_hold()
        for _ in range(4):
            chain.move_by_offset(width // 12, 0)
        chain.release().perform()

    await browser.run(drag)
    await browser.wait(lambda d: d.find_element(By.ID, "h-reset").is_enabled())
    href = await attribute(browser, "#h-csv", "href")
    asked = parse_qs(urlsplit(href).query)
    assert asked["format"] == ["csv"]
    assert set(asked) >= {"since", "until"}
    await browser.click("#h-csv")
    csv_file = tmp_path / _csv_name(href)
    await browser.wait(lambda _: csv_file.exists() and csv_file.stat().st_size > 0)
    lines = csv_file.read_text(encoding="utf-8").splitlines()
    assert lines[0] == "time,output_frequency_hz,output_current_a"
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z,[-\d.]+,[-\d.]+", lines[1])


def _csv_name(href: str) -> str:
    """The file the history's CSV link names: pump1-<since, to the minute>.csv."""
    since = parse_qs(urlsplit(href).query)["since"][0]
    return f"pump1-{since[:16].replace(':', '')}.csv"


ADMIN_PAGES = {
    "history": ("/history?drive=pump1&window=15m", "#h-charts .chart canvas"),
    "configuration": ("/configuration", "#c-versions tbody tr"),
}


async def test_the_new_pages_fit_a_phone_a_tablet_and_a_desktop(
    console: tuple[Application, Browser],
) -> None:
    _, browser = console
    await browser.login("ada", ADMIN_PASSWORD)
    await browser.wait(showing("#who", "ada (admin)"))
    for size, (width, height) in SIZES.items():
        await browser.resize(width, height)
        for page, (path, filled) in ADMIN_PAGES.items():
            await browser.open(path)
            await browser.wait(present(filled))
            fits = await browser.run(browser.driver.execute_script, FITS)
            assert fits["page"] <= width, f"{page} at {size}: {fits['page']} px wide"
            await browser.screenshot(f"{page}-{size}")


async def test_an_admin_checks_applies_and_sees_the_diff_an_operator_is_refused(
    console: tuple[Application, Browser],
) -> None:
    app, browser = console
    await browser.login("olga", OPERATOR_PASSWORD)
    await browser.wait(showing("#who", "olga (operator)"))
    assert "Configuration" not in await browser.text("nav")
    await browser.open("/configuration")
    assert "admins only" in await browser.text("body")
    await browser.click("#logout")
    await browser.wait(lambda d: "/login" in d.current_url)

    await browser.login("ada", ADMIN_PASSWORD)
    await browser.wait(showing("#who", "ada (admin)"))
    await browser.click("nav a[href='/configuration']")
    await browser.wait(showing("#live", "ready"))
    text = await attribute(browser, "#c-text", "value")
    assert 'password_hash: "***1"' in text
    assert "scrypt$" not in text

    async def edit(new: str) -> None:
        script = "document.getElementById('c-text').value = arguments[0];"
        await browser.run(browser.driver.execute_script, script, new)

    await edit(text.replace("address: 2", "address: 300"))
    await browser.click("#c-check")
    await browser.wait(showing("#c-result .problems", "drives[1] (fan2).address:"))
    await browser.click("#c-apply")
    await browser.wait(showing("#c-result", "Does not check out: nothing applied."))
    await browser.screenshot("configuration-problem")

    # A change that waits for a restart is said so before anything is applied.
    await edit(text.replace("anonymous_view: true", "anonymous_view: false"))
    await browser.click("#c-apply")
    alert = await browser.wait(expected_conditions.alert_is_present())
    assert "console.anonymous_view" in alert.text
    await browser.run(alert.dismiss)
    assert app.settings.source.console.anonymous_view is True
    await browser.wait(showing("#c-result .restart", "console.anonymous_view"))

    await edit(text.replace("timeout_ms: 100", "timeout_ms: 150"))
    await browser.type("#c-note", "longer cable")
    await browser.click("#c-apply")
    await browser.wait(showing("#c-result", "Applied as version 2"), 10.0)
    await browser.wait(showing("#c-result .changed", "buses reopened: line1"))
    assert app.settings.source.buses[0].timeout_ms == 150
    await browser.wait(showing("#c-versions tbody", "longer cable"))
    await browser.click("#c-versions button[data-show='2']")
    await browser.wait(showing("#c-diff", "+  timeout_ms: 150"))
    await browser.screenshot("configuration")

    # A file the console can't write (marked read-only here): said when the page loads, and
    # Apply is off rather than failing after the edit.
    path = Path((await browser.text("#c-path")).split(" · ")[0])
    await asyncio.to_thread(path.chmod, 0o444)
    await browser.open("/configuration")
    await browser.wait(showing("#c-read-only", f"{path} cannot be changed from the console"))
    assert "marked read-only (mode 0444)" in await browser.text("#c-read-only")
    assert await attribute(browser, "#c-apply", "disabled") == "true"
    await browser.screenshot("configuration-read-only")


async def test_numbers_line_up_right_and_the_overview_reflows_on_a_tablet(
    console: tuple[Application, Browser],
) -> None:
    _, browser = console
    await browser.resize(1400, 1000)
    await browser.open("/monitor/line1")
    await browser.wait(lambda d: d.find_elements(By.CSS_SELECTOR, "#traffic tbody td.num"))
    align = "return getComputedStyle(document.querySelector('#traffic td.num')).textAlign;"
    assert await browser.run(browser.driver.execute_script, align) == "right"
    assert "wire" in await browser.text("#traffic tbody td.num")  # the time split under it
    await browser.resize(768, 1024)
    await browser.open("/")
    await browser.wait(lambda d: d.find_elements(By.CSS_SELECTOR, "#drives tr[data-drive=pump1]"))
    inside = """const box = document.querySelector('#drives').closest('.scroll');
    return [box.scrollWidth, box.clientWidth];"""
    scroll, client = await browser.run(browser.driver.execute_script, inside)
    assert scroll <= client, f"the drives table scrolls inside its box: {scroll} > {client}"


X_AXIS = "return document.querySelector('#h-charts .chart').dataset.xLabels || '';"


async def test_history_opens_on_the_live_15_minutes_and_one_point_keeps_a_clock_axis(
    console: tuple[Application, Browser],
) -> None:
    """History opened from the menu: the live quarter-hour, a point a second, its time axis in
    clock times. A stretch holding one point keeps an axis of that stretch's seconds, not
    years."""
    _, browser = console
    await browser.open("/history")
    await browser.wait(lambda d: charts(d) == ["output_frequency_hz", "output_current_a"])
    await browser.wait(showing("#h-count", "one per 1 s"))
    assert "live, last 15 minutes" in await browser.text("#h-count")
    assert await attribute(browser, "#h-window", "value") == "15m"
    await axis_in_clock_times(browser)
    answer = await browser.run(
        browser.driver.execute_async_script,
        """const done = arguments[arguments.length - 1];
        done(await (await fetch('/api/drives/pump1/history?window=15m')).json());""",
    )
    at = answer["columns"][0][-1]  # one point's time: a stretch of 0.6 s around it
    since, until = (iso_time(at - 0.3), iso_time(at + 0.3))
    await browser.open(f"/history?drive=pump1&since={since}&until={until}")
    await browser.wait(showing("#h-count", "1 point, one per"))
    await browser.wait(lambda d: len(charts(d)) == 2)
    labels = await axis_in_clock_times(browser)
    assert all(re.fullmatch(r"\d\d:\d\d:\d\d", label) for label in labels), labels
    await browser.screenshot("history-one-point")


async def axis_in_clock_times(browser: Browser) -> list[str]:
    """The time axis's labels: two or more, each a time of day, none repeated."""

    # uPlot draws its axes on the next animation frame after the chart is made; a live chart
    # that has just opened may hold a second's points, with one label, until the next ones.
    def two_or_more(driver: Any) -> str | bool:
        text = driver.execute_script(X_AXIS) or ""
        return text if len(text.split()) >= 2 else False

    drawn = await browser.wait(two_or_more)
    labels: list[str] = drawn.split()
    assert len(labels) >= 2, labels
    assert all(re.fullmatch(r"\d\d:\d\d(:\d\d)?", label) for label in labels), labels
    assert len(set(labels)) == len(labels), labels
    return labels
