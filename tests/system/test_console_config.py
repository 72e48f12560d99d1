"""`invt-gateway hash-password`: the password hashes and tokens the `console:` section takes."""

from __future__ import annotations

from gateway.config import parse_config
from gateway.passwords import token_matches, verify_password
from tests.support.console_support import config_with
from tests.support.processes import run_cli


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
