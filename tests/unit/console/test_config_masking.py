"""The configuration's text as the console shows it: each secret as "***N", and a "***N" sent
back taken as the file's N-th secret wherever its line went, so an edit keeps every secret as it
is and never hands one user's hash to another."""

from __future__ import annotations

import yaml

from gateway.console.config_editor import diff, mask_problems, masked, unmasked

FILE = """\
mqtt:
  host: broker.plant
  username: gateway
  password: "s3cret # not a comment"   # the broker's
console:
  users:
    - name: alice
      password_hash: scrypt$16384$8$1$aaaa$bbbb
      token_hash: null
    - {name: bob, password_hash: scrypt$16384$8$1$cccc$dddd}
    - name: carol
      password_hash: scrypt$16384$8$1$eeee$ffff
      token_hash: sha256$0123
"""


def test_every_secret_is_masked_block_and_flow_and_nothing_else() -> None:
    shown = masked(FILE)
    for secret in ("s3cret", "aaaa", "cccc", "eeee", "sha256$0123"):
        assert secret not in shown
    assert '  password: "***1"   # the broker\'s\n' in shown
    assert '    - {name: bob, password_hash: "***3"}\n' in shown
    assert "      token_hash: null\n" in shown  # not set: nothing to hide
    assert "  username: gateway\n" in shown
    assert yaml.safe_load(shown)["console"]["users"][2]["token_hash"] == "***5"  # still YAML


def test_a_secret_left_masked_is_the_files_own_again() -> None:
    edited = masked(FILE).replace("host: broker.plant", "host: broker2.plant")
    assert unmasked(edited, FILE) == FILE.replace("host: broker.plant", "host: broker2.plant")


def test_a_secret_typed_anew_is_taken_as_typed() -> None:
    edited = masked(FILE).replace('  password: "***1"', "  password: n3w")
    restored = unmasked(edited, FILE)
    assert "  password: n3w " in restored
    assert "password_hash: scrypt$16384$8$1$aaaa$bbbb" in restored


def test_a_user_removed_leaves_the_next_ones_hash_with_it() -> None:
    lines = masked(FILE).splitlines(keepends=True)
    without_alice = "".join(lines[:6] + lines[9:])
    users = yaml.safe_load(unmasked(without_alice, FILE))["console"]["users"]
    assert users[0] == {"name": "bob", "password_hash": "scrypt$16384$8$1$cccc$dddd"}
    assert users[1]["password_hash"] == "scrypt$16384$8$1$eeee$ffff"
    assert users[1]["token_hash"] == "sha256$0123"


def test_a_number_the_file_has_not_is_left_for_the_check_to_refuse() -> None:
    edited = masked(FILE).replace('"***4"', '"***9"')
    assert 'password_hash: "***9"' in unmasked(edited, FILE)
    [(key, reason)] = mask_problems(edited, FILE)
    assert key == "password_hash"
    assert reason.startswith('"***9" stands for no secret of the file (it has ***1 to ***')


def test_a_diff_never_shows_a_secret() -> None:
    after = FILE.replace("s3cret", "other-secret").replace("broker.plant", "broker2.plant")
    shown = diff(FILE, after, 2)
    assert "-  host: broker.plant\n+  host: broker2.plant\n" in shown
    assert "secret" not in shown.replace("# the broker's", "")
    assert "aaaa" not in shown
