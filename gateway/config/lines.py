"""Where each key and list item of a YAML file is: its line, for reporting a problem as a
person finds it in the file (`line 7: buses[0] (line1).baudrat: unknown key`)."""

from __future__ import annotations

from typing import TypeAlias

import yaml

Location: TypeAlias = tuple[str | int, ...]
"""A place in the file as pydantic's `loc` names it: ('buses', 0, 'baudrate')."""


def key_lines(text: str) -> dict[Location, int]:
    """Each key's and list item's line (1-based) in `text`, a YAML file that parses; {} for an
    empty one."""
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    found: dict[Location, int] = {}
    if root is not None:
        _walk(root, (), found)
    return found


def _walk(node: yaml.Node, where: Location, found: dict[Location, int]) -> None:
    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            if isinstance(key, yaml.ScalarNode):
                place = (*where, str(key.value))
                found[place] = key.start_mark.line + 1
                _walk(value, place, found)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            place = (*where, index)
            found[place] = item.start_mark.line + 1
            _walk(item, place, found)


def line_of(where: Location, lines: dict[Location, int]) -> int | None:
    """The line of `where`, or of the nearest place around it that the file has (a missing
    key: the item it is missing from)."""
    for end in range(len(where), 0, -1):
        line = lines.get(where[:end])
        if line is not None:
            return line
    return None
