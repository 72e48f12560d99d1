"""`invt-gateway demo` opens the console: on loopback, anonymous view, a fresh operator password
printed in its banner (a real demo subprocess, the console reached over HTTP)."""

from __future__ import annotations

import asyncio
import re
import signal
from pathlib import Path

import aiohttp
import yaml

from gateway.instruments.commands.demo import demo_config_text
from tests.support import free_port
from tests.support.processes import entry_point


async def test_the_demo_prints_the_console_address_and_an_operator_password(
    tmp_path: Path,
) -> None:
    config = yaml.safe_load(demo_config_text(None))
    del config["mqtt"]  # this test is about the console: no broker touched
    config_file = tmp_path / "demo.yaml"
    config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
    console_port = free_port()
    process = await asyncio.create_subprocess_exec(
        *(entry_point(), "demo", "--config", str(config_file), "--port", "0"),
        *("--console-port", str(console_port)),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.DEVNULL,
    )
    try:
        assert process.stdout is not None
        banner = ""
        async with asyncio.timeout(20):
            while "Stop with Ctrl-C" not in banner:
                line = (await process.stdout.readline()).decode()
                assert line, f"the demo ended: {banner}"
                banner += line
        url = f"http://127.0.0.1:{console_port}/"
        assert f"The console: open {url} in a browser" in banner
        found = re.search(r"log in as operator, password (\S+)", banner)
        assert found is not None, banner
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as web:
            async with web.get(f"{url}api/overview") as response:  # anonymous view
                assert response.status == 200
                names = [d["name"] for d in (await response.json())["drives"]]
                assert names == ["pump1", "fan2", "conveyor3"]
            login = {"name": "operator", "password": found.group(1)}
            async with web.post(f"{url}api/login", json=login) as response:
                assert response.status == 200
                assert (await response.json())["role"] == "operator"
        process.send_signal(signal.SIGINT)
        assert await asyncio.wait_for(process.wait(), 10) == 0
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
