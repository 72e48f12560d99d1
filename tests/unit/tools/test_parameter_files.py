"""A parameter file as the field tools read and write it: in the manual's units, read back to the
same raw words, and checked whole before anything is written, each mistake named by its key."""

from __future__ import annotations

import re

import pytest
import yaml

from gateway.profile import get_profile
from gateway.tools.params import ParameterSet, from_yaml, to_yaml

GD350 = 0x01A0
"""2103H of a GD350 (the manual's identification codes)."""


def test_a_file_holds_the_manuals_units_and_reads_back_to_the_same_words() -> None:
    saved = ParameterSet(get_profile("gd350"), {"P00.03": 5000, "P00.11": 100})
    text = to_yaml(saved, GD350, address=1, saved_at=0)
    document = yaml.safe_load(text)
    assert (document["model"], document["series"], document["identification"]) == (
        "gd350",
        "GD350",
        "01A0H",
    )
    assert document["saved"] == "1970-01-01T00:00:00Z"
    # P00.03 max. output frequency in 0.01 Hz, P00.11 acceleration time in 0.1 s.
    assert document["parameters"]["P00"]["P00.03"]["value"] == 50.0
    assert document["parameters"]["P00"]["P00.03"]["unit"] == "Hz"
    assert document["parameters"]["P00"]["P00.11"]["value"] == 10.0
    assert document["parameters"]["P00"]["P00.11"]["unit"] == "s"
    assert from_yaml(text, "pump1.yaml").values == saved.values


def test_a_value_written_by_hand_without_its_other_keys_is_taken() -> None:
    edited = from_yaml("model: gd350\nparameters: {P00: {P00.11: 12.5}}\n", "pump1.yaml")
    assert edited.values == {"P00.11": 125}


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        (
            "model: gd350\nparameters: {P00: {P00.11: {value: 99999}}}",
            "pump1.yaml: parameters.P00.P00.11.value: 99999 is outside 0.0 s ... 3600.0 s",
        ),
        (
            "model: gd350\nparameters: {P00: {P99.99: 1}}",
            "pump1.yaml: parameters.P00.P99.99: not a parameter of GD350",
        ),
        (
            "model: gd350\nparameters: {P00: {P00.11: {value: yes}}}",
            "pump1.yaml: parameters.P00.P00.11.value: expected a number, got True",
        ),
        (
            "model: gd350\nparameters: {P00: [1]}",
            "pump1.yaml: parameters.P00: expected Pxx.yy entries",
        ),
        ("model: gd999\nparameters: {}", "pump1.yaml: model: unknown drive profile 'gd999'"),
        ("just some text", "pump1.yaml: not a parameter file (no 'model' and 'parameters')"),
        ("model: [gd350", "pump1.yaml: not valid YAML"),
    ],
)
def test_a_bad_file_is_refused_naming_the_key_and_the_reason(text: str, problem: str) -> None:
    with pytest.raises(ValueError, match=f"^{re.escape(problem)}"):
        from_yaml(text, "pump1.yaml")


def test_a_hex_shown_beside_a_value_must_agree_with_it() -> None:
    # The hex is only shown: an edit to it alone would be silently lost, so it is refused.
    text = "model: gd350\nparameters: {P00: {P00.11: {value: 100, hex: '0x0065'}}}"
    with pytest.raises(ValueError, match=r"P00.11.hex: 0x0065 is not value 100: edit value"):
        from_yaml(text, "pump1.yaml")
