"""A headless Chromium driven by Selenium through chromium-driver (Debian's): what a person sees
and clicks in the console. Selenium's calls block, so they run in a thread while the gateway
serves on the test's event loop."""

from __future__ import annotations

import asyncio
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from selenium import webdriver
from selenium.common.exceptions import StaleElementReferenceException
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

T = TypeVar("T")


CHROMIUM = shutil.which("chromium")


CHROMEDRIVER = shutil.which("chromedriver")


ARTIFACTS = Path(
    os.environ.get("INVT_GATEWAY_ARTIFACTS", Path(__file__).resolve().parents[2] / "test-artifacts")
)


class Browser:
    """A headless Chromium; every call in a thread so the gateway's loop keeps serving."""

    def __init__(self, base: str) -> None:
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM or ""
        for argument in (
            "--headless=new",
            "--no-sandbox",  # root in a container: Chromium's sandbox needs user namespaces
            "--disable-gpu",
            "--disable-dev-shm-usage",
            "--window-size=1400,1000",
            "--lang=en-GB",
        ):
            options.add_argument(argument)
        self.driver = webdriver.Chrome(options=options, service=Service(CHROMEDRIVER or ""))
        self.base = base

    async def run(self, call: Callable[..., T], *args: Any) -> T:
        def again_if_redrawn() -> T:
            # The live pages redraw their tables every half second: an element found just
            # before a redraw is gone when used. Find it again.
            for _ in range(20):
                try:
                    return call(*args)
                except StaleElementReferenceException:
                    continue
            return call(*args)

        return await asyncio.to_thread(again_if_redrawn)

    async def open(self, path: str) -> None:
        await self.run(self.driver.get, f"{self.base}{path}")

    async def wait(self, condition: Callable[[Any], Any], within_s: float = 5.0) -> Any:
        waiter = WebDriverWait(self.driver, within_s, poll_frequency=0.05)
        return await self.run(waiter.until, condition)

    async def text(self, selector: str) -> str:
        return str(await self.run(lambda: self.driver.find_element(By.CSS_SELECTOR, selector).text))

    async def click(self, selector: str) -> None:
        await self.run(lambda: self.driver.find_element(By.CSS_SELECTOR, selector).click())

    async def type(self, selector: str, text: str) -> None:
        def typing() -> None:
            field = self.driver.find_element(By.CSS_SELECTOR, selector)
            field.clear()
            field.send_keys(text)

        await self.run(typing)

    async def login(self, name: str, password: str) -> None:
        await self.open("/login")
        await self.type("#login-name", name)
        await self.type("#login-password", password)
        await self.click("#login-submit")

    async def resize(self, width: int, height: int) -> None:
        """The page's viewport exactly this size, as on a phone or tablet of that size."""
        metrics = {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}
        await self.run(self.driver.execute_cdp_cmd, "Emulation.setDeviceMetricsOverride", metrics)

    async def screenshot(self, name: str) -> Path:
        ARTIFACTS.joinpath("console").mkdir(parents=True, exist_ok=True)
        path = ARTIFACTS / "console" / f"{name}.png"
        await asyncio.sleep(0.3)  # a picture for a person: let the last update paint
        assert await self.run(self.driver.save_screenshot, str(path))
        return path

    def close(self) -> None:
        self.driver.quit()


def showing(selector: str, text: str) -> Callable[[Any], bool]:
    """True once an element matching `selector` holds `text`."""

    def check(driver: Any) -> bool:
        return any(text in e.text for e in driver.find_elements(By.CSS_SELECTOR, selector))

    return check
