"""The MQTT bridge (aiomqtt): drive telemetry and events out, acknowledged commands in.

- `topics`: the topic names, a public interface (Zigbee2MQTT's conventions).
- `outbox`: the bounded hand-over from the poller, which never waits for the broker.
- `requests`: command payloads read into bus requests, answers written back (no I/O); what a
  command means in registers is the profile's (`gateway.profile.commands`).
- `commands`: the safety checks, then the requests carried to the drives through the router.
- `discovery`: Home Assistant MQTT discovery messages (no I/O).
- `connection`: client id, TLS, last will, reconnect backoff.
- `session`: the connection loop: connect, back off, TLS retry, subscribe, online/offline.
- `publisher`: info, discovery, states, availability and events out, de-duplicated.
- `event_link`: the events on the session's connection, or on one of their own.
- `outage`: running values polled while a connection is away, kept in the store, delivered
  once it is back (history messages; the Sparkplug edge node's historical DDATA).
- `dispatcher`: received messages to their command kind, in lanes; busy and internal errors.
- `kinds`: the kinds of message (`/set`, `/get`, `bridge/request/<op>`, ...), a registry.
- `lanes`: received messages handled off the receive loop, in order per drive, bounded.
- `stats`: the bridge's counters.
- `bridge`: `MqttBridge`, the feature that puts the jobs above together.
"""

from gateway.mqtt.bridge import MqttBridge

__all__ = ["MqttBridge"]
