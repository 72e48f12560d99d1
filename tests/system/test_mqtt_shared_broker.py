"""Gateways sharing a broker never step on each other: a second gateway on a live gateway's base
topic is refused at start (exit code 4, saying whose it is and which keys to change), and so is
a reload that would move a running gateway onto it (`invt-gateway reload` exits 3, SIGHUP logs
it; the running configuration stays), while the same gateway started again right after a
SIGKILL (its last will not yet out) starts as usual."""

from __future__ import annotations

import asyncio
import json
import signal
from pathlib import Path
from typing import Any

import yaml

from gateway.exit_codes import EXIT_CONFIG, EXIT_STARTUP
from tests.support import free_port
from tests.support.mosquitto import Mosquitto, mqtt_probe, retained_messages, unique_base_topic
from tests.support.mosquitto import mosquitto as mosquitto
from tests.support.mqtt_setup import FAST_POLL, simulated_line
from tests.support.processes import gateway_process, run_cli


def config(gateway_id: str, line: str, broker: Mosquitto, base: str) -> dict[str, Any]:
    return {
        "gateway_id": gateway_id,
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line, "baudrate": 115200}],
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1, "model": "gd350", "poll": FAST_POLL},
        ],
        "mqtt": {"servers": [f"{broker.host}:{broker.port}"], "base_topic": base},
    }


async def test_a_second_gateway_on_a_live_base_topic_is_refused(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    base = unique_base_topic()
    with simulated_line((1,)) as line_a, simulated_line((1,)) as line_b:
        async with mqtt_probe(mosquitto, f"{base}/bridge/state") as probe:
            with gateway_process(config("cabinet-a", line_a.path, mosquitto, base), tmp_path):
                await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
                copied = config("cabinet-b", line_b.path, mosquitto, base)
                with gateway_process(copied, tmp_path) as second:
                    code = await asyncio.to_thread(second.wait, 15.0)
                    assert code == EXIT_STARTUP
                    error = second.log.text
                    assert "gateway 'cabinet-a'" in error
                    assert f"mqtt.base_topic {base!r}" in error
                # The first was never disturbed: still online, as itself.
                mark = len(probe.messages)
                await asyncio.sleep(0.3)  # asserting an absence: no "offline" from the refusal
                assert all(m.json()["state"] == "online" for m in probe.messages[mark:])


async def test_a_second_gateway_leaves_the_first_ones_entities_and_state_alone(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    """The Home Assistant entities of a gateway are its gateway id's: a copy with that id on
    another base topic is refused at start (it would republish them onto its own topics and,
    at its stop, leave them pointing at its "offline"); another gateway beside it starts and
    stops. Neither touches the first's discovery configs or its "online"."""
    site = unique_base_topic()
    a_base, b_base, prefix = f"{site}/a", f"{site}/b", f"{site}-ha"

    def with_prefix(settings: dict[str, Any]) -> dict[str, Any]:
        settings["mqtt"]["discovery_prefix"] = prefix
        return settings

    with simulated_line((1,)) as line_a, simulated_line((1,)) as line_b:
        first = with_prefix(config("cabinet-a", line_a.path, mosquitto, a_base))
        async with mqtt_probe(mosquitto, f"{a_base}/bridge/state") as probe:
            with gateway_process(first, tmp_path) as a:
                await asyncio.to_thread(a.log.wait_for, "Home Assistant discovery published")
                await probe.wait_for(f"{a_base}/bridge/state", lambda s: s["state"] == "online")
                entities = await retained_messages(mosquitto, f"{prefix}/#")
                assert len(entities) > 5
                copied = with_prefix(config("cabinet-a", line_b.path, mosquitto, b_base))
                elsewhere = tmp_path / "copy"  # its file beside the first's, same name
                elsewhere.mkdir()
                # A store of its own: the same gateway id's default store would be refused
                # first (a store has one owner), and it is the broker's check on trial here.
                copied["storage"] = {"path": str(elsewhere / "events.db")}
                with gateway_process(copied, elsewhere) as second:
                    assert await asyncio.to_thread(second.wait, 15.0) == EXIT_STARTUP
                    assert "gateway 'cabinet-a' is online already" in second.log.text
                    assert f"mqtt.base_topic {a_base!r}" in second.log.text
                other = with_prefix(config("cabinet-b", line_b.path, mosquitto, b_base))
                with gateway_process(other, tmp_path) as b:
                    await asyncio.to_thread(b.wait_ready)
                    await asyncio.to_thread(b.log.wait_for, "Home Assistant discovery published")
                # B stopped (SIGTERM): its own entities went offline, the first's are as they were.
                mark = len(probe.messages)
                after = await retained_messages(mosquitto, f"{prefix}/#")
                assert {t: p for t, p in after.items() if "/invt_cabinet-a/" in t} == entities
                await asyncio.sleep(0.3)  # asserting an absence: no "offline" for the first
                assert all(m.json()["state"] == "online" for m in probe.messages[mark:])
                state = await retained_messages(mosquitto, f"{a_base}/bridge/#")
                assert json.loads(state[f"{a_base}/bridge/state"])["state"] == "online"
                assert a.process.poll() is None


async def test_the_check_asks_the_next_server_when_the_first_is_down(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    """A cluster's first listed node down (nothing listens there): the broker behind the next
    one is asked, and the copied configuration is still refused."""
    base = unique_base_topic()
    with simulated_line((1,)) as line_a, simulated_line((1,)) as line_b:
        async with mqtt_probe(mosquitto, f"{base}/bridge/state") as probe:
            with gateway_process(config("cabinet-a", line_a.path, mosquitto, base), tmp_path):
                await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
                copied = config("cabinet-b", line_b.path, mosquitto, base)
                live = f"{mosquitto.host}:{mosquitto.port}"
                copied["mqtt"]["servers"] = [f"127.0.0.1:{free_port()}", live]
                with gateway_process(copied, tmp_path) as second:
                    assert await asyncio.to_thread(second.wait, 15.0) == EXIT_STARTUP
                    assert "gateway 'cabinet-a'" in second.log.text


async def test_the_same_gateway_started_again_before_its_last_will_starts(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    base = unique_base_topic()
    with simulated_line((1,)) as line:
        settings = config("cabinet-a", line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/bridge/state") as probe:
            # Its previous run, killed a moment ago: the broker hasn't published its will yet.
            previous = {
                "state": "online",
                "server": "10.0.0.9:1883",
                "gateway_id": "cabinet-a",
                "client_id": "invt-gateway-cabinet-a",
            }
            await probe.publish(f"{base}/bridge/state", previous, retain=True)
            await probe.wait_for(f"{base}/bridge/state")  # our own, echoed
            mark = len(probe.messages)
            with gateway_process(settings, tmp_path) as again:
                await asyncio.to_thread(again.wait_ready)
                state = await probe.wait_for(
                    f"{base}/bridge/state", lambda s: s["server"] != "10.0.0.9:1883", after=mark
                )
                assert state.json()["state"] == "online"
                assert again.process.poll() is None


async def test_a_reload_onto_a_live_gateways_base_topic_is_refused(
    mosquitto: Mosquitto, tmp_path: Path
) -> None:
    site = unique_base_topic()
    a_base, b_base = f"{site}/a", f"{site}/b"
    states = (f"{a_base}/bridge/state", f"{b_base}/bridge/state")
    with simulated_line((1,)) as line_a, simulated_line((1,)) as line_b:
        async with mqtt_probe(mosquitto, *states, f"{b_base}/pump1") as probe:
            with (
                gateway_process(config("cabinet-a", line_a.path, mosquitto, a_base), tmp_path),
                gateway_process(config("cabinet-b", line_b.path, mosquitto, b_base), tmp_path) as b,
            ):
                for topic in states:
                    await probe.wait_for(topic, lambda s: s["state"] == "online", timeout_s=15)
                # Cabinet B's file edited onto cabinet A's base topic (a copied line).
                edited = config("cabinet-b", line_b.path, mosquitto, a_base)
                b.config_file.write_text(yaml.safe_dump(edited), encoding="utf-8")
                mark = len(probe.messages)
                refused = await asyncio.to_thread(run_cli, "reload", "--config", str(b.config_file))
                assert refused.returncode == EXIT_CONFIG, refused.stdout + refused.stderr
                assert refused.stdout == ""
                assert refused.stderr.startswith(f"refused: {b.config_file}: ")
                assert "gateway 'cabinet-a'" in refused.stderr
                assert f"mqtt.base_topic {a_base!r}" in refused.stderr
                b.log.wait_for("reload refused, the running configuration stays")
                # SIGHUP (no one to answer): refused the same way, in the log.
                b.signal(signal.SIGHUP)
                b.log.wait_for_count("reload refused", 2)
                # B goes on as it ran: a fault on its drive shows on its own base topic; A's
                # base topic never heard from B; neither said offline.
                line_b.inject_fault(1, 11)
                await probe.wait_for(f"{b_base}/pump1", lambda s: s["fault_code"] == 11, after=mark)
                seen = [m.json() for m in probe.messages[mark:] if m.topic in states]
                assert all(state["state"] == "online" for state in seen), seen
                on_a = [m.json() for m in probe.messages if m.topic == states[0]]
                assert all(state["gateway_id"] == "cabinet-a" for state in on_a), on_a
                assert b.process.poll() is None
                assert "config reloaded" not in b.log.text

                # The same file on a base topic of its own is applied.
                moved = config("cabinet-b", line_b.path, mosquitto, f"{site}/b2")
                b.config_file.write_text(yaml.safe_dump(moved), encoding="utf-8")
                async with mqtt_probe(mosquitto, f"{site}/b2/bridge/state") as moved_probe:
                    applied = await asyncio.to_thread(
                        run_cli, "reload", "--config", str(b.config_file)
                    )
                    assert applied.returncode == 0, applied.stderr
                    await moved_probe.wait_for(
                        f"{site}/b2/bridge/state", lambda s: s["state"] == "online", timeout_s=15
                    )
