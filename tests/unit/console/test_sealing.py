"""A kept version's secrets sealed with the box's key file: opened again exactly by the same box,
refused (409, naming the key) by another, and a key file this gateway didn't make not used."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.console.sealing import SecretSeal
from gateway.errors import EditRefused


def seal_of(store: Path) -> SecretSeal:
    return SecretSeal(lambda: str(store))


def test_a_sealed_value_opens_again_exactly_and_hides_what_it_holds(tmp_path: Path) -> None:
    store = tmp_path / "events.db"
    value = '"s3cret: with # and \\" inside"'
    text = f"mqtt:\n  password: {seal_of(store).seal(value)}\n"
    assert "s3cret" not in text
    # Another start of the same box: the key is read from its file.
    assert seal_of(store).open_all(text, "version 2") == f"mqtt:\n  password: {value}\n"


def test_a_value_sealed_on_another_box_is_refused_naming_the_key(tmp_path: Path) -> None:
    elsewhere = seal_of(tmp_path / "a" / "events.db")
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    text = f"password: {elsewhere.seal('plain')}\n"
    with pytest.raises(EditRefused) as refused:
        seal_of(tmp_path / "b" / "events.db").open_all(text, "version 7")
    assert refused.value.status == 409
    assert "version 7" in str(refused.value)
    assert "events.db.secrets-key" in str(refused.value)


def test_a_key_file_it_did_not_make_is_not_used(tmp_path: Path) -> None:
    store = tmp_path / "events.db"
    Path(f"{store}.secrets-key").write_text("not a key\n", encoding="utf-8")
    with pytest.raises(OSError, match="not a key this gateway made"):
        seal_of(store).seal("plain")
