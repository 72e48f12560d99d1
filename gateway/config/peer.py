"""What differs between the two boxes' configurations of a redundant pair (`redundancy:`,
`check-config --peer FILE`): both boxes are one gateway, so they must agree on everything the
drives, SCADA and the broker see (the buses' settings, the drives and their poll groups, the
Modbus-TCP port and access rules, the MQTT broker and base topic, the gateway id...), and may
differ only in what is each box's own (`OWN`): its name, its peer, its hold-off, starting
role and fault file, the addresses it binds, its adapters' device paths, its store's path and
its logging.

Compared as loaded (defaults filled in): a key left out on one box and set to its default on
the other is no difference. A list of named items (buses, drives, poll groups, users) is
compared by name, so `drives[pump].poll[state].interval_ms` says which one differs.

The running boxes compare the same split between them on MQTT (`shared_digests`: each shared
key with a digest of its value, never the value; `differing` names the keys whose digests
differ): a reload on one box tells the other's operator (`gateway.redundancy.peer_config`).
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass
from typing import Any, Final

from gateway.config.schema import GatewayConfig

OWN: Final = (
    re.compile(r"^redundancy\.(box|peer|hold_off_ms|role|fault_file)$"),
    re.compile(r"^(?!mqtt\.)(.+\.)?(host|bind)$"),  # this box's addresses (not the broker's)
    re.compile(r"^buses\[[^]]+\]\.port$"),  # each box's adapter: its own device path
    re.compile(r"^storage\.path$"),
    re.compile(r"^logging\."),
)
"""Dotted keys each box may set its own way."""

SECRET: Final = re.compile(r"password|secret|token|private_key", re.IGNORECASE)
"""Keys whose values are not printed: "(differs)" only."""


@dataclass(frozen=True, slots=True)
class Difference:
    key: str
    here: Any
    there: Any
    own: bool
    """One of the keys each box may set its own way (`OWN`)."""

    def describe(self) -> str:
        if SECRET.search(self.key):
            return f"{self.key}: (differs; a secret, not shown)"
        return f"{self.key}: {_shown(self.here)} here, {_shown(self.there)} on the peer"


def differences(here: GatewayConfig, there: GatewayConfig) -> list[Difference]:
    """Every key whose value differs between the two boxes' files, in key order."""
    mine = dict(_flat(here.model_dump(mode="json")))
    theirs = dict(_flat(there.model_dump(mode="json")))
    keys = sorted(mine.keys() | theirs.keys())
    missing = "(not set)"
    return [
        Difference(key, mine.get(key, missing), theirs.get(key, missing), _own(key))
        for key in keys
        if mine.get(key, missing) != theirs.get(key, missing)
    ]


def shared_digests(config: GatewayConfig) -> dict[str, str]:
    """Each key both boxes must share (not `OWN`), with a digest of its value as loaded: the
    first 12 hex digits of the SHA-256 of its JSON. A secret's digest says only whether it is
    set: a digest of a password on the broker could be guessed offline (`check-config --peer`
    compares the values)."""
    digests: dict[str, str] = {}
    for key, value in _flat(config.model_dump(mode="json")):
        if _own(key):
            continue
        if SECRET.search(key):
            value = "(secret: set)" if value not in (None, "") else value
        text = json.dumps(value, sort_keys=True, separators=(",", ":"))
        digests[key] = hashlib.sha256(text.encode()).hexdigest()[:12]
    return digests


def _own(key: str) -> bool:
    return any(pattern.search(key) for pattern in OWN)


def _flat(value: Any, prefix: str = "") -> list[tuple[str, Any]]:
    if isinstance(value, dict):
        pairs: list[tuple[str, Any]] = []
        for key, item in value.items():
            pairs += _flat(item, f"{prefix}.{key}" if prefix else str(key))
        return pairs
    if isinstance(value, list) and value and all(_named(item) for item in value):
        pairs = []
        for item in value:
            pairs += _flat(item, f"{prefix}[{item['name']}]")
        return pairs
    if isinstance(value, list) and any(isinstance(item, dict | list) for item in value):
        pairs = []
        for index, item in enumerate(value):
            pairs += _flat(item, f"{prefix}[{index}]")
        return pairs or [(prefix, value)]
    return [(prefix, value)]


def _named(item: Any) -> bool:
    return isinstance(item, dict) and isinstance(item.get("name"), str)


def _shown(value: Any) -> str:
    if isinstance(value, float) and value.is_integer():
        return str(int(value))  # 200 ms, as the file says it, not 200.0
    return value if isinstance(value, str) else repr(value)
