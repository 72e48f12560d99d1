"""Each Sparkplug device's metrics: names, aliases, datatypes and properties in its birth, then
what changed by alias. No I/O.

A drive's metrics are its telemetry keys, named as in its JSON state (`output_frequency_hz`,
`state`, `fault_code`, a device file's points, a limit alarm's flag), each with its `engUnit`
and `readOnly` properties; with commands enabled, a `commands/<name>` Boolean per control
command its profile takes (write true to run it). `set_frequency_hz` and a device file's
writable points take writes too (`readOnly` false).

Aliases are the edge node's: unique across the node and all its devices (the specification
asks it), and the same for a metric at every birth while the gateway runs. What the birth
declared is what DDATA may carry: a key that appears later, or a value whose datatype changed,
asks for a new DBIRTH of that device instead (a host refuses data for a metric it wasn't born
with). DDATA carries only the keys with news by the report-by-exception rules (`mqtt.report`,
a drive's `report`, a device file's points' own): the same rules as the JSON state's.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final

from gateway.profile import DriveProfile
from gateway.profile.registers import RUNNING_VALUES
from gateway.profile.report_by_exception import ExceptionReport
from gateway.profile.telemetry import Telemetry
from gateway.sparkplug.payload import (
    BOOLEAN,
    DOUBLE,
    INT32,
    INT64,
    BirthMetric,
    DataMetric,
    Value,
    datatype_of,
)

COMMAND_PREFIX: Final = "commands/"
SETPOINT: Final = "set_frequency_hz"
"""The set-point's metric: the drive's set frequency as read back, written as `frequency_hz`."""
NOT_PUBLISHED: Final = frozenset({"last_seen"})
"""The payload's timestamp says when; `last_seen` would make every poll news."""
WIDER: Final[Mapping[int, frozenset[int]]] = {
    INT32: frozenset({INT64, DOUBLE}),
    INT64: frozenset({DOUBLE}),
}
"""A datatype whose values a birth's other datatype carries as they are (a whole number read
where the birth said Double)."""
NUMBERS: Final = frozenset({INT32, INT64, DOUBLE})
"""The datatypes `datatype_of` gives a number."""


class Aliases:
    """The edge node's metric aliases, handed out once per (device, metric) and then kept."""

    def __init__(self) -> None:
        self._aliases: dict[tuple[str, str], int] = {}

    def of(self, device: str, name: str) -> int:
        key = (device, name)
        alias = self._aliases.get(key)
        if alias is None:
            alias = self._aliases[key] = len(self._aliases) + 1
        return alias


def unit_of(profile: DriveProfile, key: str) -> str:
    """A telemetry key's engineering unit: a device file's point's, or its register's."""
    for point in profile.typed_points:
        if point.name == key:
            return point.unit
    for running in RUNNING_VALUES:
        if running.key == key:
            return running.register.unit
    return ""


class DeviceMetrics:
    """One drive's (or device's) metrics on this edge node."""

    def __init__(
        self,
        device: str,
        profile: DriveProfile,
        report: ExceptionReport,
        aliases: Aliases,
        commands_enabled: bool,
    ) -> None:
        self.device = device
        self.profile = profile
        self.report = report
        self.aliases = aliases
        self.commands_enabled = commands_enabled
        self.commands = profile.commands
        """The commands a DCMD may name (refused as the `/set` path refuses them when commands
        are disabled); the birth declares them only when enabled."""
        self.writable = frozenset(
            {p.name for p in profile.typed_points if p.writable}
            | ({SETPOINT} if self.commands else set())
        )
        self._declared: dict[str, int] = {}
        """Metric → its datatype, as the last birth declared it."""
        self._sent: dict[str, Value] = {}
        """Key → the value last published, for the keys no report-by-exception rule watches."""

    def birth(self, telemetry: Telemetry, now: float) -> list[BirthMetric]:
        """The DBIRTH's metrics for `telemetry`; what DDATA may carry from now on."""
        reading = _reading(telemetry)
        metrics = [self._birth_metric(key, value) for key, value in reading.items()]
        metrics += [
            BirthMetric(
                COMMAND_PREFIX + command,
                self.aliases.of(self.device, COMMAND_PREFIX + command),
                BOOLEAN,
                False,
                {"readOnly": False, "documentation": f"write true: {command} (DCMD)"},
            )
            for command in (self.commands if self.commands_enabled else ())
        ]
        self._declared = {m.name: m.datatype for m in metrics}
        self.report.published(reading, now)
        self._sent = dict(reading)
        return metrics

    def changes(self, telemetry: Telemetry, now: float) -> list[DataMetric] | None:
        """DDATA's metrics: the keys with news (maybe none); None when a new birth is due (a
        key the birth didn't declare, or a value of another datatype)."""
        reading = _reading(telemetry)
        for key, value in reading.items():
            declared = self._declared.get(key)
            found = datatype_of(value)
            if declared is None or (
                found != declared and declared not in WIDER.get(found, frozenset())
            ):
                return None
        changed = self.report.changed(reading, now)
        # A key no rule watches (a device file's limit alarm flag) goes out when it differs:
        # DDATA is all a host gets, there is no whole state republished now and then.
        changed += [
            key
            for key, value in reading.items()
            if not self.report.watches(key) and self._sent.get(key) != value
        ]
        self.report.published({key: reading[key] for key in changed}, now)
        self._sent.update({key: reading[key] for key in changed})
        return [
            DataMetric(self.aliases.of(self.device, key), self._declared[key], reading[key])
            for key in changed
        ]

    def historical(self, values: Mapping[str, Value]) -> list[tuple[int, int, Value]]:
        """(alias, datatype, value) of each of `values` this birth declared with a datatype that
        carries it: values polled earlier, sent as they were (no report-by-exception: each was
        news when it was kept)."""
        found = []
        for key, value in values.items():
            declared = self._declared.get(key)
            if declared is None:
                continue
            kind = datatype_of(value)
            if kind == declared or declared in WIDER.get(kind, frozenset()):
                found.append((self.aliases.of(self.device, key), declared, value))
        return found

    def declared(self) -> list[tuple[int, int]]:
        """(alias, datatype) of every metric the birth declared but the commands."""
        return [
            (self.aliases.of(self.device, name), datatype)
            for name, datatype in self._declared.items()
            if not name.startswith(COMMAND_PREFIX)
        ]

    def forget(self) -> None:
        """The device died (DDEATH) or the node is born again: its next birth starts afresh."""
        self._declared = {}

    @property
    def born(self) -> bool:
        return bool(self._declared)

    def name_of(self, alias: int) -> str | None:
        """The metric a DCMD names by its alias."""
        for name in self._declared:
            if self.aliases.of(self.device, name) == alias:
                return name
        return None

    def kind_mismatch(self, name: str, value: Value | None) -> str | None:
        """Why a DCMD's `value` can't be `name`'s (a number for a Boolean, text for a number);
        None when it can, or when the birth did not declare `name`."""
        declared = self._declared.get(name)
        if declared is None or value is None:
            return None
        found = datatype_of(value)
        if _kind(found) == _kind(declared):
            return None
        return f"a {_kind(found)} for a {_kind(declared)} metric"

    def _birth_metric(self, key: str, value: Value) -> BirthMetric:
        writable = self.commands_enabled and key in self.writable
        properties: dict[str, Value] = {"readOnly": not writable}
        unit = unit_of(self.profile, key)
        if unit:
            properties["engUnit"] = unit
        return BirthMetric(
            key, self.aliases.of(self.device, key), datatype_of(value), value, properties
        )


def _kind(datatype: int) -> str:
    """What a datatype holds, as far as a command's value goes: widths don't matter here."""
    if datatype == BOOLEAN:
        return "boolean"
    return "number" if datatype in NUMBERS else "text"


def _reading(telemetry: Mapping[str, Value]) -> dict[str, Value]:
    return {key: value for key, value in telemetry.items() if key not in NOT_PUBLISHED}
