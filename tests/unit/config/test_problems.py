"""How a file's problems are reported: each under the key path a person finds in the file (an item
by its index and its name), with a reason in plain words, each once, all of them in one go."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.config import ENV_MQTT_PASSWORD, ENV_MQTT_USERNAME, load_config, parse_config
from gateway.errors import ConfigError

BUS = {"name": "line1", "port": "/dev/ttyUSB0"}


def problems(file: dict[str, Any] | str) -> list[tuple[str, str]]:
    """Every (key path, reason) loading the file reports; a path of "" is carried in the reason."""
    text = file if isinstance(file, str) else yaml.safe_dump(file)
    with pytest.raises(ConfigError) as error:
        parse_config(text, "plant.yaml")
    assert str(error.value).startswith("plant.yaml: invalid configuration\n")
    return error.value.problems


def drive(name: str, address: int, **keys: Any) -> dict[str, Any]:
    return {"name": name, "bus": "line1", "address": address, **keys}


def test_a_key_inside_a_list_item_is_named_by_index_and_name_at_every_level() -> None:
    poll = [{"name": "fast", "start": 0x2100, "count": 200, "interval_ms": 100}]
    assert problems({"buses": [BUS], "drives": [drive("pump1", 1, poll=poll)]}) == [
        ("drives[0] (pump1).poll[0] (fast).count", "Input should be less than or equal to 125")
    ]


def test_an_item_without_a_name_is_named_by_its_index_alone() -> None:
    assert problems({"buses": [BUS], "drives": [{"bus": "line1", "address": 1}]}) == [
        ("drives[0].name", "required key is missing")
    ]


def test_unknown_and_missing_keys_say_so_in_words() -> None:
    unknown = problems({"buses": [{**BUS, "baud": 9600}]})
    assert unknown == [("buses[0] (line1).baud", "unknown key; did you mean baudrate?")]
    assert problems({"drives": []}) == [("buses", "required key is missing")]


def test_a_checks_own_reason_is_shown_without_pydantics_prefix() -> None:
    ((path, reason),) = problems({"buses": [BUS], "console": {"cert_file": "/etc/hosts"}})
    assert path == "console"
    assert reason.startswith("cert_file and key_file go together")


def test_a_clash_across_sections_is_reported_once_naming_both_items() -> None:
    found = problems({"buses": [BUS], "drives": [drive("pump1", 1), drive("pump1", 2)]})
    assert found == [("", "drives[1] (pump1).name: duplicate name pump1 (also drives[0] (pump1))")]


def test_clashes_are_reported_beside_invalid_fields_in_one_go() -> None:
    second = drive("pump1", 1, timeout_ms=-1)
    assert problems({"buses": [BUS], "drives": [drive("pump1", 1), second]}) == [
        ("drives[1] (pump1).timeout_ms", "Input should be greater than 0"),
        ("", "drives[1] (pump1).name: duplicate name pump1 (also drives[0] (pump1))"),
        ("", "drives[1] (pump1).unit_id: duplicate unit_id 1 (also drives[0] (pump1))"),
        (
            "",
            "drives[1] (pump1).address: duplicate address 1 on bus line1 (also drives[0] (pump1))",
        ),
    ]


def test_an_access_rule_for_a_unit_id_no_drive_has_is_named() -> None:
    access = [{"name": "scada", "unit_ids": [9], "allow": ["read"]}]
    found = problems(
        {"buses": [BUS], "drives": [drive("pump1", 1)], "modbus_tcp": {"access": access}}
    )
    assert (
        "",
        "modbus_tcp.access[0] (scada).unit_ids: no drive has unit id 9 (drives: 1; 0 is broadcast)",
    ) in found


def test_a_file_that_is_not_a_mapping_or_not_there_says_what_it_is(tmp_path: Path) -> None:
    assert problems("- line1\n- line2\n") == [("", "the file must be a YAML mapping (key: value)")]
    with pytest.raises(ConfigError) as error:
        load_config(tmp_path / "nowhere.yaml")
    ((path, reason),) = error.value.problems
    assert path == ""
    assert reason.startswith("cannot read the file: ")
    assert error.value.source == str(tmp_path / "nowhere.yaml")


def test_the_brokers_credentials_from_the_environment_win_over_the_files(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    text = yaml.safe_dump(
        {"buses": [BUS], "mqtt": {"host": "10.0.0.5", "username": "file", "password": "file"}}
    )
    monkeypatch.setenv(ENV_MQTT_USERNAME, "plant")
    monkeypatch.setenv(ENV_MQTT_PASSWORD, "from the environment")
    mqtt = parse_config(text).mqtt
    assert mqtt is not None
    assert (mqtt.username, mqtt.password) == ("plant", "from the environment")
    monkeypatch.delenv(ENV_MQTT_PASSWORD)
    mqtt = parse_config(text).mqtt
    assert mqtt is not None
    assert mqtt.password == "file"
