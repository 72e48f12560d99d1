"""The MQTT topics of one gateway, after Zigbee2MQTT's conventions (a public interface).

| topic                                 | dir | retained | what                              |
|---------------------------------------|-----|----------|-----------------------------------|
| <base>/bridge/state                   | out | yes      | {"state": "online"}; the last     |
|                                       |     |          | will {"state": "offline"}         |
| <base>/bridge/info                    | out | yes      | gateway id, version, drives       |
| <base>/bridge/event                   | out | no       | fault_raised, fault_cleared,      |
|                                       |     |          | drive_offline, drive_online,      |
|                                       |     |          | retained_command_cleared          |
| <base>/bridge/request/read_parameter  | in  | refused  | read any Pxx.yy or register       |
| <base>/bridge/request/write_parameter | in  | refused  | write any Pxx.yy or register      |
| <base>/bridge/response/<op>           | out | no       | the answer, with `transaction`    |
| <base>/<drive>                        | out | yes      | state, fault, running values      |
| <base>/<drive>/availability           | out | yes      | {"state": "online" / "offline"}   |
| <base>/<drive>/set                    | in  | refused  | a command or a parameter write    |
| <base>/<drive>/set/response           | out | no       | the acknowledgement               |
| <base>/<drive>/get                    | in  | ignored  | poll now, publish the state       |
| <base>/<drive>/history                | out | no       | running values polled while the   |
|                                       |     |          | broker was away, with their times |

A command that comes retained is refused (`retained`) and cleared from the broker (an empty
retained publish; a `retained_command_cleared` event says so); an empty payload on a command
topic is ignored quietly (that is how a retained message is cleared).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Topics:
    base: str

    @property
    def bridge_state(self) -> str:
        return f"{self.base}/bridge/state"

    @property
    def bridge_info(self) -> str:
        return f"{self.base}/bridge/info"

    @property
    def bridge_event(self) -> str:
        return f"{self.base}/bridge/event"

    def bridge_request(self, operation: str) -> str:
        return f"{self.base}/bridge/request/{operation}"

    def bridge_response(self, operation: str) -> str:
        return f"{self.base}/bridge/response/{operation}"

    def drive_state(self, drive: str) -> str:
        return f"{self.base}/{drive}"

    def availability(self, drive: str) -> str:
        return f"{self.base}/{drive}/availability"

    def history(self, drive: str) -> str:
        return f"{self.base}/{drive}/history"

    def set(self, drive: str) -> str:
        return f"{self.base}/{drive}/set"

    def set_response(self, drive: str) -> str:
        return f"{self.base}/{drive}/set/response"

    def get(self, drive: str) -> str:
        return f"{self.base}/{drive}/get"

    def drive_of(self, topic: str) -> str | None:
        """The drive a `<base>/<drive>/set` or `/get` topic names; None for any other topic."""
        prefix = f"{self.base}/"
        if not topic.startswith(prefix):
            return None
        parts = topic[len(prefix) :].split("/")
        if len(parts) == 2 and parts[1] in ("set", "get") and parts[0] != "bridge":
            return parts[0]
        return None
