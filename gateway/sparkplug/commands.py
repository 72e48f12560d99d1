"""A DCMD's metrics as the `/set` path's commands. No I/O.

    commands/<name> = true        {"command": name}          (false: nothing to do; a button
                                                               that writes itself back)
    set_frequency_hz = 35.0       {"frequency_hz": 35.0}     (with a command in the same DCMD:
                                                               one message, run at 35 Hz)
    <writable point> = v          {"point": name, "value": v}

The DCMD's timestamp becomes the command's `time`, so a DCMD that waited somewhere longer than
`mqtt.command_max_age_s` is refused as stale, as a JSON command would be. What the payloads then
go through (retained refusal, `commands_enabled`, the writes, the `command` event) is
`gateway.mqtt.commands`', the same code as `/set`'s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gateway.mqtt.requests import Json
from gateway.sparkplug.metrics import COMMAND_PREFIX, SETPOINT, DeviceMetrics
from gateway.sparkplug.payload import Received


@dataclass(slots=True)
class DeviceCommand:
    """What one DCMD asks of its drive: `/set` payloads in order, and what was not understood."""

    payloads: list[Json] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


def device_command(received: Received, metrics: DeviceMetrics) -> DeviceCommand:
    result = DeviceCommand()
    control: Json = {}
    points: list[Json] = []
    for metric in received.metrics:
        name = metric.name
        aliased = None if metric.alias is None else metrics.name_of(metric.alias)
        if name is None:
            name = aliased
        if name is None:
            result.problems.append(f"alias {metric.alias}: no metric of {metrics.device} has it")
            continue
        if metric.alias is not None and aliased != name:
            # The birth made them one metric: a DCMD that names two can't say which it means.
            result.problems.append(
                f"{name}: alias {metric.alias} is {aliased or 'no metric'} "
                f"of {metrics.device}, not this one"
            )
            continue
        mismatch = metrics.kind_mismatch(name, metric.value)
        if mismatch:
            result.problems.append(f"{name}: {mismatch}")
        elif metric.value is None:
            result.problems.append(f"{name}: no value")
        elif name.startswith(COMMAND_PREFIX):
            _command(name.removeprefix(COMMAND_PREFIX), metric.value, metrics, control, result)
        elif name == SETPOINT and name in metrics.writable:
            control["frequency_hz"] = metric.value
        elif name in metrics.writable:
            points.append({"point": name, "value": metric.value})
        else:
            result.problems.append(f"{name}: not a writable metric of {metrics.device}")
    result.payloads = ([control] if control else []) + points
    if received.timestamp_ms:
        for payload in result.payloads:
            payload["time"] = received.timestamp_ms
    return result


def _command(
    command: str, value: object, metrics: DeviceMetrics, control: Json, result: DeviceCommand
) -> None:
    if command not in metrics.commands:
        result.problems.append(f"{COMMAND_PREFIX}{command}: {metrics.device} has no such command")
    elif value is not True:
        pass  # false: a momentary button written back; nothing to run
    elif "command" in control:
        result.problems.append(
            f"{COMMAND_PREFIX}{command}: one command per DCMD ({control['command']} came first)"
        )
    else:
        control["command"] = command
