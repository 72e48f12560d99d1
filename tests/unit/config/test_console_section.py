"""The `console:` section as the configuration reads it: its defaults, and a bad value named by
its key and reason."""

from __future__ import annotations

import pytest
import yaml

from gateway.config import parse_config
from gateway.errors import ConfigError
from tests.support.console_support import BASE, config_with


def test_the_console_is_off_on_loopback_8080_unless_configured() -> None:
    console = parse_config(yaml.safe_dump(BASE)).console
    assert (console.enabled, console.host, console.port) == (False, "127.0.0.1", 8080)
    assert (console.anonymous_view, console.commands_enabled) == (False, True)


@pytest.mark.parametrize(
    ("console", "problem"),
    [
        (
            {"users": [{"name": "a", "password_hash": "hunter22", "role": "operator"}]},
            "console.users[0] (a).password_hash: not a password hash",
        ),
        (
            {"users": [{"name": "a", "password_hash": "x", "role": "superuser"}]},
            "console.users[0] (a).role: Input should be 'viewer', 'operator' or 'admin'",
        ),
        ({"cert_file": "/etc/hosts"}, "cert_file and key_file go together"),
        ({"enabled": True}, "nobody could use it"),
        ({"key_file": "/nonexistent/key.pem"}, "/nonexistent/key.pem: no such file"),
        ({"port": 70000}, "console.port"),
    ],
)
def test_a_bad_console_section_names_the_key_and_the_reason(
    console: dict[str, object], problem: str
) -> None:
    with pytest.raises(ConfigError) as error:
        parse_config(config_with(console), "gateway.yaml")
    assert problem in str(error.value)
