"""The field tools' words for where they go and for what went wrong: `--via` read as a gateway's
address, and each exception a drive answers turned into what to check on site."""

from __future__ import annotations

import re

import pytest

from gateway.profile import exception_codes as code
from gateway.tools.advice import exception_error
from gateway.tools.masters import parse_via


def test_via_is_a_gateways_address_its_port_5020_unless_given() -> None:
    assert parse_via("tcp://10.0.0.5:1502") == ("10.0.0.5", 1502)
    assert parse_via("tcp://gateway.plant") == ("gateway.plant", 5020)


@pytest.mark.parametrize("url", ["10.0.0.5:5020", "http://10.0.0.5", "tcp://", "tcp://h:99999"])
def test_a_via_that_is_no_gateway_address_says_what_is_expected(url: str) -> None:
    with pytest.raises(ValueError, match=re.escape(repr(url))):
        parse_via(url)


def test_an_exception_is_named_with_the_checks_it_points_to() -> None:
    error = exception_error(code.OPERATION_FAILURE, "writing P00.04 at address 1")
    assert error.exception_code == code.OPERATION_FAILURE
    assert error.message.startswith("writing P00.04 at address 1: exception 04H")
    assert any("P00.04 within P00.05" in check for check in error.checks)  # a range bound


def test_a_command_the_drive_refuses_points_at_its_command_channel() -> None:
    error = exception_error(code.ILLEGAL_COMMAND, "writing 2000H at address 1")
    assert any("P00.01 = 2" in check for check in error.checks)


def test_an_exception_without_a_checklist_is_still_named() -> None:
    error = exception_error(0x0C, "reading 2100H at address 1")
    assert error.checks == ()
    assert str(error).startswith("reading 2100H at address 1: exception 0CH")
