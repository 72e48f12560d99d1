"""A traffic monitor held open on the console during a bench case, as a browser would hold it:
its stream read to the end, every transaction decoded by the gateway and sent."""

from __future__ import annotations

import asyncio

import aiohttp


async def watch_traffic(console_port: int, stop: asyncio.Event) -> int:
    """Read the line's traffic stream until `stop`; the transactions it carried."""
    url = f"http://127.0.0.1:{console_port}/api/buses/line1/traffic"
    seen = 0
    async with aiohttp.ClientSession() as session, session.get(url) as response:
        if response.status != 200:
            raise RuntimeError(f"{url}: {response.status} {await response.text()}")
        stopping = asyncio.create_task(stop.wait())
        try:
            while not stop.is_set():
                reading = asyncio.create_task(response.content.readline())
                done, _ = await asyncio.wait(
                    {reading, stopping}, return_when=asyncio.FIRST_COMPLETED
                )
                if reading not in done:
                    reading.cancel()
                    break
                line = reading.result()
                if not line:
                    raise RuntimeError(f"{url}: the gateway ended the stream")
                if line.startswith(b"event: traffic"):
                    seen += 1
        finally:
            stopping.cancel()
    if not seen:
        raise RuntimeError(f"{url}: the monitor saw no transaction")
    return seen
