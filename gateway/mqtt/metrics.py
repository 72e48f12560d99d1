"""The MQTT bridge's metric families, read at scrape time from the bridge: connected or not,
messages published and dropped, commands answered by status."""

from __future__ import annotations

from collections.abc import Iterable

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from gateway.metric_families import PREFIX
from gateway.mqtt.bridge import MqttBridge


class MqttMetrics(Collector):
    def __init__(self, bridge: MqttBridge) -> None:
        self.bridge = bridge

    def collect(self) -> Iterable[CounterMetricFamily | GaugeMetricFamily]:
        bridge = self.bridge
        connected = GaugeMetricFamily(
            f"{PREFIX}_mqtt_connected", "1 while the bridge is connected to the broker"
        )
        connected.add_metric([], 1.0 if bridge.connected.is_set() else 0.0)
        yield connected
        server = GaugeMetricFamily(
            f"{PREFIX}_mqtt_server_info",
            "1 for the broker of mqtt.servers the bridge uses (or tries next), 0 for the others",
            labels=["server"],
        )
        in_use = bridge.session.server_name
        for name in bridge.session.server_names():
            server.add_metric([name], 1.0 if name == in_use else 0.0)
        yield server
        yield CounterMetricFamily(
            f"{PREFIX}_mqtt_messages_published",
            "Messages the bridge published (states, availability, events, answers, discovery)",
            value=bridge.stats.published,
        )
        yield CounterMetricFamily(
            f"{PREFIX}_mqtt_messages_dropped",
            "Events dropped before the broker had them (the store's bounds: the broker was away "
            "too long); states are never dropped, only superseded by newer ones",
            value=bridge.publisher.events.stats.events_dropped,
        )
        commands = CounterMetricFamily(
            f"{PREFIX}_mqtt_commands",
            "Commands answered, by status: ok, or why not (retained, stale, busy, ...)",
            labels=["status"],
        )
        statuses = dict(bridge.commands.statuses)
        statuses["busy"] = statuses.get("busy", 0) + bridge.stats.busy  # refused before their turn
        for status, count in sorted(statuses.items()):
            commands.add_metric([status], count)
        yield commands
