"""The MQTT bridge (aiomqtt): drive telemetry and events out, acknowledged commands in.

- `topics`: the topic names, a public interface (Zigbee2MQTT's conventions).
- `outbox`: the bounded hand-over from the poller, which never waits for the broker.
- `requests`: command payloads read into bus requests, answers written back (no I/O).
- `commands`: the safety checks, then the requests carried to the drives through the router.
- `discovery`: Home Assistant MQTT discovery messages (no I/O).
- `connection`: client id, TLS, last will, reconnect backoff.
- `lanes`: received messages handled off the receive loop, in order per drive, bounded.
- `bridge`: `MqttBridge`, the feature that connects, publishes and receives.
- `embedded_broker`: a tiny loopback broker so `invt-gateway demo` needs nothing installed.
"""

from gateway.mqtt.bridge import MqttBridge

__all__ = ["MqttBridge"]
