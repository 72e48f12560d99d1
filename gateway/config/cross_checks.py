"""The checks across sections: names, ports, unit ids and addresses unique, each drive on a
defined bus, each access rule's unit ids a drive's. One message per problem, naming the item's
key path and the other item it clashes with.

`schema.GatewayConfig` runs them on a valid file; `loading` runs them on an invalid one too (the
invalid fields taken as unreadable), so that one run reports every problem.
"""

from __future__ import annotations

from collections.abc import Sequence

from gateway.config.sections.buses import BusConfig
from gateway.config.sections.drives import DriveConfig
from gateway.config.sections.modbus_tcp import AccessRuleConfig


def cross_field_problems(
    buses: Sequence[BusConfig], drives: Sequence[DriveConfig], access: Sequence[AccessRuleConfig]
) -> list[str]:
    """Every problem across the sections, one line each, in the order the file is read."""
    problems: list[str] = []
    if not buses:
        problems.append("buses: at least one bus is required")
    _unique(problems, "buses", "name", [(b.name, b.name) for b in buses])
    _unique(problems, "buses", "port", [(b.name, b.port) for b in buses])
    _unique(problems, "drives", "name", [(d.name, d.name) for d in drives])
    _unique(problems, "drives", "unit_id", [(d.name, d.effective_unit_id) for d in drives])
    _unique(problems, "drives", "address", [(d.name, (d.bus, d.address)) for d in drives])
    bus_names = {b.name for b in buses}
    problems += _access_unit_problems(drives, access)
    for index, drive in enumerate(drives):
        if drive.bus not in bus_names:
            known = ", ".join(sorted(bus_names))
            problems.append(
                f"drives[{index}] ({drive.name}).bus: bus {drive.bus!r} is not defined "
                f"(buses: {known})"
            )
    return problems


def _access_unit_problems(
    drives: Sequence[DriveConfig], access: Sequence[AccessRuleConfig]
) -> list[str]:
    """A rule naming a unit id no drive has is most likely a typo that would protect nothing."""
    known = {d.effective_unit_id for d in drives}
    shown = ", ".join(map(str, sorted(known))) or "none"
    problems = []
    for index, rule in enumerate(access):
        label = f" ({rule.name})" if rule.name else ""
        for unit_id in rule.unit_ids or ():
            if unit_id != 0 and unit_id not in known:
                problems.append(
                    f"modbus_tcp.access[{index}]{label}.unit_ids: no drive has unit id "
                    f"{unit_id} (drives: {shown}; 0 is broadcast)"
                )
    return problems


def _unique(problems: list[str], section: str, key: str, items: list[tuple[str, object]]) -> None:
    """Report every item whose value of `key` an earlier item already has."""
    seen: dict[object, tuple[int, str]] = {}
    for index, (name, value) in enumerate(items):
        if value in seen:
            shown = value if not isinstance(value, tuple) else f"{value[1]} on bus {value[0]}"
            first, first_name = seen[value]
            problems.append(
                f"{section}[{index}] ({name}).{key}: duplicate {key} {shown} "
                f"(also {section}[{first}] ({first_name}))"
            )
        else:
            seen[value] = (index, name)
