"""Real HTTP against a running gateway's metrics port: a GET as a scraper or a probe makes it,
and a Prometheus exposition read into its samples."""

from __future__ import annotations

import asyncio
import urllib.error
import urllib.request

from prometheus_client.parser import text_string_to_metric_families


async def http_get(port: int, path: str, host: str = "127.0.0.1") -> tuple[int, str, str]:
    """(status, content type, body) of a real HTTP GET."""

    def get() -> tuple[int, str, str]:
        url = f"http://{host}:{port}{path}"
        try:
            with urllib.request.urlopen(url, timeout=5) as response:
                return response.status, response.headers["Content-Type"], response.read().decode()
        except urllib.error.HTTPError as error:
            return error.code, error.headers["Content-Type"], error.read().decode()

    return await asyncio.to_thread(get)


class Scrape:
    """Every sample of a Prometheus exposition; `scrape("requests_total", bus=...)` is one value
    (names without the `invt_gateway_` prefix; other metrics by their full name)."""

    def __init__(self, text: str) -> None:
        self.samples = {
            (sample.name, frozenset(sample.labels.items())): sample.value
            for family in text_string_to_metric_families(text)
            for sample in family.samples
        }

    def __call__(self, name: str, **labels: str) -> float:
        full = name if name.startswith("process_") else f"invt_gateway_{name}"
        return self.samples[(full, frozenset(labels.items()))]
