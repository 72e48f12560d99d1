"""A drive's report by exception on a real broker: an output current jittering inside its
deadband costs no publishes beyond the heartbeat; a step outside it is published at once."""

from __future__ import annotations

import asyncio
import time

from tests.support import running_gateway
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mosquitto import mosquitto as mosquitto
from tests.support.mqtt_setup import FAST_POLL, mqtt_config, simulated_line

QUIET_S = 4.0
HEARTBEAT_S = 3


async def test_a_jittering_current_is_published_only_with_the_heartbeat(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    drive = {
        "name": "pump1",
        "address": 1,
        "model": "gd350",
        "poll": FAST_POLL,  # the running values every 300 ms: a dozen polls while quiet
        "report": {"keys": {"output_current_a": {"deadband": 1.0}}},
    }
    with simulated_line(addresses=(1,)) as line:
        line.set_output_current(1, 5.0, jitter_a=0.4)
        config = mqtt_config(
            line.path,
            mosquitto,
            base,
            drives=[drive],
            publish_interval_s=HEARTBEAT_S,
            report={"deadband_percent": 0.5},
        )
        topic = f"{base}/pump1"
        async with mqtt_probe(mosquitto, topic) as probe, running_gateway(config):
            await probe.wait_for(topic, lambda s: "output_current_a" in s)
            mark = len(probe.messages)
            await asyncio.sleep(QUIET_S)
            quiet = probe.messages[mark:]
            currents = {m.json()["output_current_a"] for m in quiet}
            # Only the heartbeat: one per HEARTBEAT_S (a poll's lateness may add one).
            assert len(quiet) <= QUIET_S // HEARTBEAT_S + 1, [m.json() for m in quiet]
            assert currents <= {4.6, 4.7, 4.8, 4.9, 5.0, 5.1, 5.2, 5.3, 5.4}

            mark = len(probe.messages)
            line.set_output_current(1, 8.0)
            stepped = time.monotonic()
            moved = await probe.wait_for(
                topic, lambda s: s["output_current_a"] == 8.0, after=mark, timeout_s=2.0
            )
            assert moved.at - stepped < 1.0  # at the next poll, not the heartbeat
