"""The Modbus-TCP access rules as pure functions: which registers a request touches, which rule
decides, and the exception code a refused request gets (01H: function refused, 02H: register)."""

from __future__ import annotations

from gateway.tcp.access import AccessPolicy, AccessRule, merge_spans, touched_spans
from tests.support import read_pdu, write_many, write_pdu


def policy(*rules: AccessRule) -> AccessPolicy:
    return AccessPolicy(rules)


def test_first_match_wins_and_no_match_allows() -> None:
    rules = policy(
        AccessRule(allow=True, functions=frozenset({3})),
        AccessRule(allow=False, unit_ids=frozenset({1})),
    )
    assert rules.check(1, read_pdu(0x2100)) is None
    refusal = rules.check(1, write_pdu(0x2000, 1))
    assert refusal is not None
    assert (refusal.rule, refusal.code) == (1, 0x01)
    assert rules.check(2, write_pdu(0x2000, 1)) is None
    assert rules.denied == [0, 1]


def test_allowed_function_at_a_forbidden_register_is_02h() -> None:
    """Whitelist style: 06H allowed at 2000H-2001H only; elsewhere 06H is an address refusal."""
    rules = policy(
        AccessRule(allow=True, functions=frozenset({6}), spans=((0x2000, 0x2001),)),
        AccessRule(allow=False),
    )
    assert rules.check(1, write_pdu(0x2001, 5)) is None
    refused_write = rules.check(1, write_pdu(0x000B, 5))
    assert refused_write is not None
    assert refused_write.code == 0x02
    refused_read = rules.check(1, read_pdu(0x2100))
    assert refused_read is not None
    assert refused_read.code == 0x01


def test_registers_each_function_touches() -> None:
    assert touched_spans(read_pdu(0x2100, 3)) == ((0x2100, 0x2102),)
    assert touched_spans(bytes.fromhex("04 FF FE 00 10")) == ((0xFFFE, 0xFFFF),)
    assert touched_spans(write_pdu(0x2000, 1)) == ((0x2000, 0x2000),)
    assert touched_spans(write_many(0x000A, 1, 2, 3)) == ((0x000A, 0x000C),)
    assert touched_spans(bytes.fromhex("16 00 0B 00 FF 00 00")) == ((0x000B, 0x000B),)
    read_write = bytes.fromhex("17 21 00 00 02 00 0B 00 01 02 00 05")
    assert touched_spans(read_write) == ((0x2100, 0x2101), (0x000B, 0x000B))
    assert touched_spans(bytes.fromhex("08 00 00 12 AB")) is None
    assert touched_spans(bytes.fromhex("03 21")) == ((0, 0xFFFF),)  # too short: everything


def test_17h_is_refused_when_its_write_half_is() -> None:
    rules = policy(AccessRule(allow=False, spans=((0x0000, 0x00FF),)))
    read_params_write_command = bytes.fromhex("17 00 0B 00 01 20 00 00 01 02 00 01")
    read_command_write_param = bytes.fromhex("17 20 00 00 01 00 0B 00 01 02 00 01")
    assert rules.check(1, bytes.fromhex("17 21 00 00 01 20 00 00 01 02 00 01")) is None
    assert rules.check(1, read_params_write_command) is not None
    assert rules.check(1, read_command_write_param) is not None


def test_a_short_request_cannot_slip_past_a_refusing_rule() -> None:
    rules = policy(
        AccessRule(allow=True, spans=((0x2000, 0x2001),)),
        AccessRule(allow=False, spans=((0x0000, 0x00FF),)),
    )
    refusal = rules.check(1, bytes.fromhex("06 00"))
    assert refusal is not None
    assert refusal.code == 0x02


def test_rules_with_registers_ignore_functions_without_registers() -> None:
    rules = policy(AccessRule(allow=False, spans=((0, 0xFFFF),)))
    assert rules.check(1, bytes.fromhex("08 00 00 12 AB")) is None


def test_a_broadcast_must_pass_as_every_unit_id() -> None:
    writes = frozenset({6})
    rules = policy(AccessRule(allow=False, unit_ids=frozenset({7}), functions=writes))
    assert rules.check(0, write_pdu(0x2000, 1)) is not None
    assert rules.check(0, read_pdu(0x2000)) is None
    general = policy(AccessRule(allow=True, unit_ids=frozenset({1})), AccessRule(allow=False))
    assert general.check(1, write_pdu(0x2000, 1)) is None
    assert general.check(0, write_pdu(0x2000, 1)) is not None  # units other than 1 are refused


def test_adjacent_spans_merge() -> None:
    assert merge_spans([(5, 9), (0, 1), (2, 3), (8, 12)]) == ((0, 3), (5, 12))
    rules = policy(AccessRule(allow=True, spans=merge_spans([(0x2000, 0x2000), (0x2001, 0x2001)])))
    assert rules.check(1, write_many(0x2000, 1, 2)) is None
