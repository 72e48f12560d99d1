"""A configuration's text checked before it is applied (the console's editor, `gateway.console.
config_editor`): every check `check-config` makes (`gateway.config.startup` included: a text
the gateway could not start on is refused), and what the live reload would do with it.

    problems        (key path, reason) for each thing wrong, as `check-config` prints them
    lines           each problem's line in the text (None where it has none)
    warnings        a serial port missing on this machine, a line its polls would fill
    changed         what the reload would apply at once (`gateway.settings.reload.plan`)
    restart_needed  what would wait for a restart, kept at its running value meanwhile
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from gateway.config import parse_config
from gateway.config.startup import startup_problems
from gateway.errors import ConfigError
from gateway.poller.budget import line_budget
from gateway.settings import GatewaySettings, runtime_settings
from gateway.settings.checks import missing_ports
from gateway.settings.reload import plan


@dataclass(frozen=True, slots=True)
class Checked:
    problems: list[tuple[str, str]] = field(default_factory=list)
    """(key path, reason); empty: valid."""
    warnings: list[str] = field(default_factory=list)
    changed: list[str] = field(default_factory=list)
    restart_needed: list[str] = field(default_factory=list)
    lines: list[int | None] = field(default_factory=list)
    """Each problem's line in the text; shorter than `problems` where a check has none."""

    @property
    def ok(self) -> bool:
        return not self.problems

    def _line(self, index: int) -> int | None:
        return self.lines[index] if index < len(self.lines) else None

    def to_json(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "problems": [
                {"key": key, "reason": reason, "line": self._line(index)}
                for index, (key, reason) in enumerate(self.problems)
            ],
            "warnings": self.warnings,
            "changed": self.changed,
            "restart_needed": self.restart_needed,
        }


def check_text(text: str, source: str, running: GatewaySettings, mqtt_running: bool) -> Checked:
    """`text` checked as the file `source` (blocks for a moment: the line budget's arithmetic,
    the ports' existence; call it off the event loop)."""
    try:
        config = parse_config(text, source)
    except ConfigError as exc:
        return Checked(list(exc.problems), lines=list(exc.lines))
    problems = startup_problems(config)
    if problems:
        return Checked(problems)
    warnings = missing_ports(config) + line_budget(runtime_settings(config))[1]
    planned = plan(running.source, config, mqtt_running=mqtt_running)
    return Checked([], warnings, planned.changed, planned.restart_needed)
