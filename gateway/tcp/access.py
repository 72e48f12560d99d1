"""Which requests a Modbus-TCP client may make: rules by unit id, function code and register.

Rules are tried in order and the first that matches decides; a request no rule matches is
allowed. A rule matches when every condition it names holds (a condition left out holds always):

- `unit_ids`   the request's unit id is one of them;
- `functions`  its function code is one of them;
- `spans`      for an allowing rule, every register the request touches lies inside the spans;
               for a refusing rule, any one does. A 10H write that touches a single forbidden
               register is therefore refused whole, and an allowing rule never lets a forbidden
               register through next to allowed ones. Only requests that address registers
               (03H 04H 06H 10H 16H 17H) can match a rule with spans.

A refused request is answered 02H (illegal data address) when the refusing rule names registers,
or when an earlier allowing rule would have taken this function at other registers: the function
is allowed, the address is not. Otherwise 01H (illegal function).

A broadcast (unit id 0) reaches every drive, so it must pass the rules as unit id 0, as every
unit id a rule names, and as a unit id no rule names.

Registers are plain numbers here: spelling them (`P00.11`, RAM-only twins) is the configuration's
business, not this layer's.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Final

from gateway.errors import ExceptionCode
from gateway.modbus.functions import lookup
from gateway.modbus.registers import Span

BROADCAST_UNIT: Final = 0


@dataclass(frozen=True, slots=True)
class AccessRule:
    allow: bool
    unit_ids: frozenset[int] | None = None
    functions: frozenset[int] | None = None
    spans: tuple[Span, ...] | None = None
    """Merged and sorted by `merge_spans`; None: any register, and requests without any."""
    label: str = ""
    """How logs and metrics name the rule (its `name`, else its place in the list)."""
    roles: frozenset[str] | None = None
    """Only for TLS clients whose certificate carries one of these roles; None: every client."""


@dataclass(frozen=True, slots=True)
class Refusal:
    rule: int
    """Index of the refusing rule."""
    code: int
    """The exception code the client gets: 01H or 02H."""


class AccessPolicy:
    """The rules of `modbus_tcp.access`, and how many requests each has refused."""

    def __init__(self, rules: Sequence[AccessRule]) -> None:
        self.rules = tuple(rules)
        self.denied = [0] * len(self.rules)
        """Requests refused, per rule (same index)."""
        named = {unit for rule in self.rules for unit in rule.unit_ids or ()}
        # None stands for "a unit id no rule names": such a drive sees only the general rules.
        self._broadcast_views: tuple[int | None, ...] = (
            BROADCAST_UNIT,
            *sorted(named - {BROADCAST_UNIT}),
            None,
        )

    def check(self, unit_id: int, pdu: bytes, role: str | None = None) -> Refusal | None:
        """None when the request may go on; else which rule refused it and with what code.

        `role`: a TLS client's role (rules with `roles` apply only to those); None otherwise.
        """
        if unit_id != BROADCAST_UNIT:
            refusal = self._decide(unit_id, pdu, role)
        else:
            refusal = next(
                (r for v in self._broadcast_views if (r := self._decide(v, pdu, role)) is not None),
                None,
            )
        if refusal is not None:
            self.denied[refusal.rule] += 1
        return refusal

    def _decide(self, unit_id: int | None, pdu: bytes, role: str | None) -> Refusal | None:
        function = pdu[0]
        touched: tuple[Span, ...] | None = None
        looked = False
        address_refused = False
        for index, rule in enumerate(self.rules):
            if rule.roles is not None and role not in rule.roles:
                continue
            if rule.unit_ids is not None and unit_id not in rule.unit_ids:
                continue
            if rule.functions is not None and function not in rule.functions:
                continue
            if rule.spans is not None:
                if not looked:  # parsed once, and only when a rule names registers
                    touched, looked = touched_spans(pdu), True
                if touched is None:
                    continue
                if rule.allow and not covers(rule.spans, touched):
                    address_refused = True
                    continue
                if not rule.allow and not overlaps(rule.spans, touched):
                    continue
            if rule.allow:
                return None
            names_address = rule.spans is not None or address_refused
            code = (
                ExceptionCode.ILLEGAL_DATA_ADDRESS
                if names_address
                else ExceptionCode.ILLEGAL_FUNCTION
            )
            return Refusal(index, int(code))
        return None


def touched_spans(pdu: bytes) -> tuple[Span, ...] | None:
    """The registers a request reads or writes; None for functions that address no registers.

    A request too short to say which registers it means is taken to touch all of them: refusing
    rules catch it, allowing rules with registers don't (the drive would refuse it anyway).
    """
    return lookup(pdu[0]).registers(pdu)


def merge_spans(spans: Iterable[Span]) -> tuple[Span, ...]:
    """Sorted, with overlapping and adjacent spans joined: 0-1 and 2-5 cover a request for 1-2."""
    merged: list[Span] = []
    for first, last in sorted(spans):
        if merged and first <= merged[-1][1] + 1:
            merged[-1] = (merged[-1][0], max(merged[-1][1], last))
        else:
            merged.append((first, last))
    return tuple(merged)


def covers(allowed: Sequence[Span], touched: Iterable[Span]) -> bool:
    """Every touched span lies inside one allowed span (`allowed` merged)."""
    return all(any(a <= first and last <= b for a, b in allowed) for first, last in touched)


def overlaps(listed: Sequence[Span], touched: Iterable[Span]) -> bool:
    return any(first <= b and a <= last for a, b in listed for first, last in touched)
