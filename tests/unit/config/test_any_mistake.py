"""Whatever a file holds in place of a value, loading it ends in a configuration or in a
ConfigError that lists each problem with its reason: never a crash (hypothesis mutates the
shipped example file)."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.config import parse_config
from gateway.errors import ConfigError

EXAMPLE = Path(__file__).resolve().parents[3] / "config" / "config.example.yaml"


ODD_VALUES = [None, [], {}, "", "x", "line1", 0, -1, 300, True, 1.5, [1, "a"], {"a": 1}, [None]]


def _key_paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    paths = [prefix] if prefix else []
    children = (
        node.items()
        if isinstance(node, dict)
        else enumerate(node)
        if isinstance(node, list)
        else ()
    )
    for key, child in children:
        paths += _key_paths(child, (*prefix, key))
    return paths


@settings(max_examples=150, deadline=None)
@given(data=st.data())
def test_any_mistake_gets_a_config_error_never_a_crash(data: st.DataObject) -> None:
    # The cross-field checks also run on files whose fields are invalid: whatever a file holds
    # in place of a value, the result is a configuration or a ConfigError listing problems.
    config = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    for _ in range(data.draw(st.integers(1, 4))):
        # Paths of the file as it is now: an earlier change may have replaced a section.
        *parents, key = data.draw(st.sampled_from(_key_paths(config)))
        node = config
        for parent in parents:
            node = node[parent]
        node[key] = copy.deepcopy(data.draw(st.sampled_from(ODD_VALUES)))
    problems = _problems_of(yaml.safe_dump(config))
    assert all(reason for _, reason in problems), problems


def _problems_of(text: str) -> list[tuple[str, str]]:
    try:
        parse_config(text, "mutated.yaml")
    except ConfigError as exc:
        return exc.problems or [("", "")]  # an error with no problem listed fails the test
    return []
