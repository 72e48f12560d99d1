"""A live reload (SIGHUP, `systemctl reload`): a new configuration applied without a restart.

What changes in place, SCADA's connections staying open and requests in flight finishing:

    buses         a bus whose settings changed is reopened alone: closed (its queued requests
                  answered 0BH, as at shutdown; the one on the wire finishes), opened again with
                  the new settings, its drives routed to it; every other bus keeps its queue
                  and its port
    drives        the router's table (a removed drive's unit id answers 0AH from then on, an
                  added one answers at once) and the poller
    modbus_tcp    access rules, read_only, allowed_networks, the per-client and per-connection
                  limits, timeouts and broadcast_reply
    metrics       host and port: the endpoint listens on the new address (on the old one still,
                  and says so, when the new one can't be had); drives added are labelled by name
    storage       max_mb and max_age_days
    logging       level

What keeps its running value until a restart, named in the log and the `config_reloaded` event
("restart needed for: ..."): the listeners (`modbus_tcp.host`, `port`, `plain`, `tls`),
`gateway_id`, `storage.path`, the console (its listener and, in this version, its other keys),
the OPC UA server's keys (every `opcua` key; its address space follows the drives: an added
drive's nodes are made, a removed one's deleted, a changed one's made again, the rest kept),
every `redundancy` key (the role machine's silence and its listeners are set at start),
and in this version buses added or removed (with the drives that would move onto or off them),
`metrics.enabled` and `mqtt.enabled`. A site's device file (`model: file:PATH`) is read again:
edited, its drive is changed as if its keys had been (its points polled and published anew).

    mqtt          any other key of the section, or drives added or removed: the bridge is
                  started again with the new settings (it says offline and online again; a
                  command being carried out over MQTT is cut off); a removed drive's topics are
                  no longer served, an added one's are, and its Home Assistant entities follow

The planning (`plan`) is pure: it compares two configurations (the user's keys, which the log
names) and says what to do, with the runtime settings of the configuration that runs afterwards;
the application (`Application.reload`) carries it out.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

from pydantic import BaseModel

from gateway.config import (
    BusConfig,
    ConsoleConfig,
    DriveConfig,
    GatewayConfig,
    MetricsConfig,
    ModbusTcpConfig,
    MqttConfig,
)
from gateway.profile import DriveProfile
from gateway.profile.device_files import FILE_PREFIX
from gateway.settings import DriveSettings, GatewaySettings, runtime_settings
from gateway.settings.local import metrics_settings

LISTENER_KEYS = ("host", "port", "plain", "tls")
"""`modbus_tcp` keys that belong to the listening sockets: a change needs a restart."""


@dataclass(slots=True)
class ReloadPlan:
    previous: GatewayConfig
    running: GatewayConfig
    """The configuration the gateway runs with afterwards: the new one, with every key that
    needs a restart kept at its running value."""
    settings: GatewaySettings
    """`running`, as runtime settings."""
    added: list[DriveSettings] = field(default_factory=list)
    removed: list[str] = field(default_factory=list)
    changed: list[str] = field(default_factory=list)
    """What is applied, as key paths and drive names."""
    restart_needed: list[str] = field(default_factory=list)
    reopened: list[str] = field(default_factory=list)
    """Buses whose settings changed: closed and opened again with the new ones."""
    restart_bridge: bool = False
    """The MQTT bridge is started again with the running configuration (its settings, or the
    drives it serves, changed)."""

    def metrics_not_moved(self, reason: str) -> None:
        """The metrics endpoint could not move to its new address: it stays where it was."""
        self.changed.remove("metrics.host/port")
        self.restart_needed.append(f"metrics.host/port ({reason})")
        self.running = self.running.model_copy(update={"metrics": self.previous.metrics})
        kept = metrics_settings(self.previous.metrics)
        self.settings = replace(self.settings, source=self.running, metrics=kept)

    @property
    def summary(self) -> str:
        applied = ", ".join(self.changed) or "nothing changed"
        if self.restart_needed:
            return f"{applied}; restart needed for: {', '.join(self.restart_needed)}"
        return applied


def plan(
    old: GatewayConfig,
    new: GatewayConfig,
    mqtt_running: bool,
    profiles: Mapping[str, DriveProfile] | None = None,
) -> ReloadPlan:
    """What to do to go from `old` to `new`. `profiles`: each running drive's profile, as its
    device file (`model: file:PATH`) was read at the last start or reload; a file edited since
    is a drive changed, though its key in the configuration is the same."""
    restart: list[str] = []
    changed: list[str] = []
    if old.gateway_id != new.gateway_id:
        restart.append("gateway_id")
    if old.storage.path != new.storage.path:
        restart.append("storage.path")
    tcp = _tcp(old.modbus_tcp, new.modbus_tcp, changed, restart)
    storage = new.storage.model_copy(update={"path": old.storage.path})
    if storage != old.storage:
        changed.append("storage")
    if new.logging != old.logging:
        changed.append("logging")
    mqtt = _mqtt(old.mqtt, new.mqtt, changed, restart)
    metrics = _metrics(old.metrics, new.metrics, changed, restart)
    restart += _console(old.console, new.console)
    restart += _waits(old.opcua, new.opcua, "opcua")
    restart += _waits(old.redundancy, new.redundancy, "redundancy")
    reopened = _buses(old, new, changed, restart)
    # Buses added or removed wait for a restart, and so do the drives that would move onto or
    # off them; on every other bus (reopened or not) drives change now.
    steady = {b.name for b in old.buses} & {b.name for b in new.buses}
    drives, added, removed = _drives(old, new, steady, changed, restart, profiles or {})
    restart_bridge = mqtt_running and ("mqtt" in changed or bool(added or removed))
    if (added or removed) and mqtt_running:
        changed.append("MQTT topics of drives added or removed")
    if (added or removed) and old.opcua.enabled:
        changed.append("OPC UA nodes of drives added or removed")
    planned = {"modbus_tcp": tcp, "storage": storage, "mqtt": mqtt, "metrics": metrics}
    running = _running(old, new, drives, planned)
    settings = runtime_settings(running)
    return ReloadPlan(
        old,
        running,
        settings,
        [settings.drive(d.name) for d in added],
        removed,
        changed,
        restart,
        reopened,
        restart_bridge,
    )


def _running(
    old: GatewayConfig,
    new: GatewayConfig,
    drives: tuple[DriveConfig, ...],
    parts: Mapping[str, object],
) -> GatewayConfig:
    """The configuration that runs after the reload: `new`, with what waits for a restart as it
    was (the gateway id, the console, buses added or removed) and `parts` as planned."""
    kept = {
        "gateway_id": old.gateway_id,
        "console": old.console,
        "opcua": old.opcua,
        "redundancy": old.redundancy,
    }
    buses = _running_buses(old, new)
    return new.model_copy(update={**kept, **parts, "buses": buses, "drives": drives})


def _mqtt(
    old: MqttConfig | None, new: MqttConfig | None, changed: list[str], restart: list[str]
) -> MqttConfig | None:
    """The broker's settings change now; turning MQTT on or off waits for a restart."""
    was_on = old is not None and old.enabled
    is_on = new is not None and new.enabled
    if was_on != is_on:
        restart.append("mqtt.enabled")  # the store's forwarding is set at start
        return old
    if old != new and is_on:
        changed.append("mqtt")
    return old if old == new else new


def _console(old: ConsoleConfig, new: ConsoleConfig) -> list[str]:
    """Every console key waits for a restart (its listener, users and sessions)."""
    return _waits(old, new, "console")


def _waits(old: BaseModel, new: BaseModel, section: str) -> list[str]:
    """Each of the section's keys that changed, as waiting for a restart."""
    return [
        f"{section}.{key}"
        for key in type(new).model_fields
        if getattr(old, key) != getattr(new, key)
    ]


def _buses(
    old: GatewayConfig, new: GatewayConfig, changed: list[str], restart: list[str]
) -> list[str]:
    """The buses to reopen (settings changed), by name; those added or removed wait."""
    before = {b.name: b for b in old.buses}
    after = {b.name: b for b in new.buses}
    reopened = [name for name, bus in after.items() if name in before and before[name] != bus]
    added = [name for name in after if name not in before]
    removed = [name for name in before if name not in after]
    if reopened:
        changed.append(f"buses reopened: {', '.join(reopened)}")
    restart += [f"bus {name} (added)" for name in added]
    restart += [f"bus {name} (removed)" for name in removed]
    return reopened


def _running_buses(old: GatewayConfig, new: GatewayConfig) -> tuple[BusConfig, ...]:
    """The buses there were, each with its new settings where the file still has it."""
    after = {b.name: b for b in new.buses}
    return tuple(after.get(b.name, b) for b in old.buses)


def _metrics(
    old: MetricsConfig, new: MetricsConfig, changed: list[str], restart: list[str]
) -> MetricsConfig:
    """The endpoint moves to a new host or port at once; turning it on or off waits."""
    if old.enabled != new.enabled:
        restart.append("metrics.enabled")
        return old
    if new != old and new.enabled:
        changed.append("metrics.host/port")
        return new
    return old


def _tcp(
    old: ModbusTcpConfig, new: ModbusTcpConfig, changed: list[str], restart: list[str]
) -> ModbusTcpConfig:
    kept = {key: getattr(old, key) for key in LISTENER_KEYS}
    restart += [f"modbus_tcp.{key}" for key in LISTENER_KEYS if getattr(new, key) != kept[key]]
    running = new.model_copy(update=kept)
    changed += [
        f"modbus_tcp.{key}"
        for key in type(new).model_fields
        if key not in LISTENER_KEYS and getattr(old, key) != getattr(new, key)
    ]
    return running


def _drives(
    old: GatewayConfig,
    new: GatewayConfig,
    steady: set[str],
    changed: list[str],
    restart: list[str],
    profiles: Mapping[str, DriveProfile],
) -> tuple[tuple[DriveConfig, ...], list[DriveConfig], list[str]]:
    """The drives to run with: new ones on steady buses (there before and after, reopened or
    not), the old ones elsewhere."""
    before = {d.name: d for d in old.drives}
    after = {d.name: d for d in new.drives}
    running: dict[str, DriveConfig] = {}
    added: list[DriveConfig] = []
    removed: list[str] = []
    for name, drive in after.items():
        was = before.get(name)
        if drive.bus not in steady or (was is not None and was.bus not in steady):
            if was is not None:
                running[name] = was
            if was != drive:
                restart.append(f"drive {name} (its bus is added or removed)")
            continue
        running[name] = drive
        if was is None:
            added.append(drive)
        elif was != drive or _device_file_changed(drive, profiles.get(name)):
            removed.append(name)  # replaced: out with the old, in with the new
            added.append(drive)
    for name, was in before.items():
        if name in after:
            continue
        if was.bus in steady:
            removed.append(name)
        else:
            running[name] = was
            restart.append(f"drive {name} (its bus is removed)")
    gone = [name for name in removed if name not in after]
    came = [d.name for d in added if d.name not in before]
    replaced = [d.name for d in added if d.name in before]
    for label, names in (("drives added", came), ("drives removed", gone)):
        if names:
            changed.append(f"{label}: {', '.join(names)}")
    if replaced:
        changed.append(f"drives changed: {', '.join(replaced)}")
    order = [d.name for d in new.drives] + [n for n in before if n not in after]
    drives = tuple(running[name] for name in order if name in running)
    return drives, added, removed


def _device_file_changed(drive: DriveConfig, running: DriveProfile | None) -> bool:
    """A site's device file edited since the running profile was read from it: the same
    `model: file:PATH`, other points (read again now; the configuration's check read it too)."""
    if running is None or not drive.model.strip().startswith(FILE_PREFIX):
        return False
    return drive.profile() != running
