"""`invt-gateway demo` opens the console: on loopback, anonymous view, a fresh operator password
and a fresh admin password printed in its banner, the admin editing a copy of the demo's
configuration (a real demo subprocess, the console reached over HTTP)."""

from __future__ import annotations

import asyncio
import re
import signal
from pathlib import Path

import aiohttp
import yaml

from gateway.instruments.commands.demo import demo_config_text
from tests.support import free_port
from tests.support.console_support import ConsoleClient
from tests.support.processes import entry_point


async def test_the_demo_prints_the_console_address_an_operator_and_an_admin_login(
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

        # The admin's login, printed the same way: the configuration can be edited in the demo.
        admin = re.search(
            r"log in as admin, password (\S+)\n.*a copy of the demo's, (\S+),", banner
        )
        assert admin is not None, banner
        password, copy = admin.groups()
        assert password != found.group(1)
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as web:
            console = ConsoleClient(web, url.rstrip("/"))
            assert (await console.login("admin", password)).status == 200
            async with web.get(url) as response:  # the menu's link leads somewhere that works
                assert 'href="/configuration"' in await response.text()
            shown = await console.get_json("/api/config/file")
            assert (shown["path"], shown["read_only"]) == (copy, None)
            longer = shown["text"].replace("timeout_ms: 300", "timeout_ms: 400")
            assert longer != shown["text"]
            edit = {"text": longer, "note": "tried in the demo", "base": shown["base"]}
            status, applied = await console.post("/api/config/apply", edit)
            assert status == 200, applied
            assert applied["changed"] == ["buses reopened: line1"]
            running = (await console.get_json("/api/config"))["configuration"]
            assert running["buses"][0]["timeout_ms"] == 400
        # The file given with --config is left as it was: the admin edits the demo's copy.
        assert yaml.safe_load(config_file.read_text(encoding="utf-8")) == config
        process.send_signal(signal.SIGINT)
        assert await asyncio.wait_for(process.wait(), 10) == 0
        assert not await asyncio.to_thread(Path(copy).exists)  # gone with the demo
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
