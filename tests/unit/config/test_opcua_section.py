"""The `opcua:` section as the configuration reads it: off by default, its defaults, a bad value
named by its key and reason; and the settings it becomes (the state directory's files, the
console's users)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from gateway.config import ENV_STATE_DIRECTORY, parse_config
from gateway.errors import ConfigError
from gateway.settings import runtime_settings
from tests.support.console_support import BASE, USERS


def file_with(opcua: dict[str, object], console: dict[str, object] | None = None) -> str:
    return yaml.safe_dump({**BASE, "opcua": opcua, "console": console or {}})


def test_opcua_is_off_on_loopback_4840_with_basic256sha256_only_unless_configured() -> None:
    config = parse_config(yaml.safe_dump(BASE))
    opcua = config.opcua
    assert (opcua.enabled, opcua.host, opcua.port) == (False, "127.0.0.1", 4840)
    assert opcua.security == ("Basic256Sha256_SignAndEncrypt", "Basic256Sha256_Sign")
    assert (opcua.anonymous, opcua.commands_enabled) == (False, True)
    assert runtime_settings(config).opcua is None


@pytest.mark.parametrize(
    ("opcua", "problem"),
    [
        ({"enabled": True}, "opcua: enabled with no console.users and anonymous false"),
        ({"security": ["Basic128Rsa15"]}, "opcua.security[0]: Input should be 'None', 'Basic25"),
        ({"security": []}, "opcua.security: no endpoint: list at least one"),
        ({"certificate_file": "/etc/hosts"}, "certificate_file and private_key_file go together"),
        ({"private_key_file": "/nonexistent/key.pem"}, "/nonexistent/key.pem: no such file"),
        ({"port": 0}, "opcua.port"),
        ({"anonymus": True}, "opcua.anonymus: unknown key; did you mean anonymous?"),
    ],
)
def test_a_bad_opcua_section_names_the_key_and_the_reason(
    opcua: dict[str, object], problem: str
) -> None:
    with pytest.raises(ConfigError) as error:
        parse_config(file_with(opcua), "gateway.yaml")
    assert problem in str(error.value)


def test_its_files_default_to_the_state_directory_and_its_users_are_the_console_s(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(ENV_STATE_DIRECTORY, str(tmp_path))
    config = parse_config(file_with({"enabled": True}, {"users": USERS}))
    opcua = runtime_settings(config).opcua
    assert opcua is not None
    assert opcua.certificate_file == tmp_path / "opcua" / "server-cert.der"
    assert opcua.private_key_file == tmp_path / "opcua" / "server-key.pem"
    assert opcua.trusted_clients_dir == tmp_path / "opcua" / "trusted"
    assert opcua.rejected_clients_dir == tmp_path / "opcua" / "rejected"
    assert opcua.make_certificate
    assert [(u.name, u.role) for u in opcua.users] == [(u["name"], u["role"]) for u in USERS]
    assert opcua.endpoint == "opc.tcp://127.0.0.1:4840/invt-gateway"
    assert opcua.application_uri == "urn:invt-gateway:invt-gateway"


def test_anonymous_alone_is_enough_to_enable_it() -> None:
    config = parse_config(file_with({"enabled": True, "anonymous": True}))
    opcua = runtime_settings(config).opcua
    assert opcua is not None
    assert (opcua.anonymous, opcua.users) == (True, ())
