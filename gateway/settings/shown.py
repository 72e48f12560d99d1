"""The running configuration as a person may see it: every key, with its secrets masked.

What the console's diagnostics page shows (and `/api/config` gives): the configuration the
gateway runs on now, after the last reload, defaults filled in, so what a file left out is visible
too. A secret's value is never shown, only whether it is set: passwords, password and token
hashes (a hash is enough to mount a guessing attack offline), and any key named like a secret.
"""

from __future__ import annotations

from typing import Any, Final

from gateway.config import GatewayConfig

MASK: Final = "***"
SECRET_WORDS: Final = ("password", "token", "secret", "private_key")


def shown_configuration(config: GatewayConfig) -> dict[str, Any]:
    shown: dict[str, Any] = _masked(config.model_dump(mode="json"))
    return shown


def _masked(value: Any) -> Any:
    if isinstance(value, dict):
        return {key: _masked_entry(key, item) for key, item in value.items()}
    if isinstance(value, list):
        return [_masked(item) for item in value]
    return value


def _masked_entry(key: str, value: Any) -> Any:
    if any(word in key.lower() for word in SECRET_WORDS):
        return None if value is None else MASK
    return _masked(value)
