"""The `console:` section and `invt-gateway hash-password`: what a person configures first."""

from __future__ import annotations

import pytest
import yaml

from gateway.config import parse_config
from gateway.errors import ConfigError
from gateway.passwords import token_matches, verify_password
from tests.support.processes import run_cli

BASE = {"buses": [{"name": "line1", "port": "/dev/ttyUSB0"}]}


def config_with(console: dict[str, object]) -> str:
    return yaml.safe_dump({**BASE, "console": console})


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


def test_hash_password_reads_a_piped_password_and_prints_a_salted_hash() -> None:
    first = run_cli("hash-password", input_text="correct horse battery\n")
    second = run_cli("hash-password", input_text="correct horse battery\n")
    assert first.returncode == 0, first.stderr
    stored = first.stdout.strip()
    assert stored.startswith("scrypt$")
    assert stored != second.stdout.strip()  # salted: the same password, another hash
    assert verify_password("correct horse battery", stored)
    assert not verify_password("correct horse battery!", stored)
    users = [{"name": "alice", "password_hash": stored, "role": "operator"}]
    assert parse_config(config_with({"users": users})).console.users[0].name == "alice"


def test_hash_password_refuses_a_short_password() -> None:
    result = run_cli("hash-password", input_text="short\n")
    assert result.returncode == 1
    assert "at least 8 characters" in result.stderr


def test_new_token_prints_a_token_and_the_hash_the_config_takes() -> None:
    result = run_cli("hash-password", "--new-token")
    lines = dict(line.split(": ", 1) for line in result.stdout.splitlines())
    token, stored = lines["token"].strip(), lines["token_hash"].strip()
    assert token_matches(token, stored)
    users = [{"name": "bot", "password_hash": _a_password_hash(), "token_hash": stored}]
    assert parse_config(config_with({"users": users})).console.users[0].token_hash == stored


def _a_password_hash() -> str:
    from gateway.passwords import hash_password

    return hash_password("a long enough password")
