"""Who may use the console, as logic: passwords and tokens checked against their hashes, sessions
bounded and ended, and failed logins slowed per name and address so that a guesser slows only
himself."""

from __future__ import annotations

import itertools

import pytest

from gateway.console.auth import (
    FIRST_DELAY_S,
    MAX_ADDRESS_FAILURES,
    MAX_DELAY_S,
    MAX_FAILURES,
    MAX_SESSIONS,
    Identity,
    LoginThrottle,
    Role,
    Sessions,
    Users,
    Via,
)
from gateway.passwords import hash_password, hash_token, new_token
from gateway.settings import ConsoleUser

ALICE_PASSWORD = "correct horse battery"
ALICE_TOKEN = new_token()


@pytest.fixture(scope="module")
def users() -> Users:
    return Users(
        [
            ConsoleUser(
                "alice", hash_password(ALICE_PASSWORD), "operator", hash_token(ALICE_TOKEN)
            ),
            ConsoleUser("bob", hash_password("bob's own password"), "viewer", None),
        ]
    )


def test_the_right_password_gives_the_users_role_and_nothing_else_does(users: Users) -> None:
    assert users.check_password("alice", ALICE_PASSWORD) is Role.OPERATOR
    assert users.check_password("alice", ALICE_PASSWORD + " ") is None
    assert users.check_password("alice", "bob's own password") is None
    assert users.check_password("mallory", ALICE_PASSWORD) is None  # no such user
    assert users.role_of("bob") is Role.VIEWER
    assert users.role_of("mallory") is None


def test_a_token_names_its_user_and_only_its_own_does(users: Users) -> None:
    identity = users.by_token(ALICE_TOKEN)
    assert identity is not None
    assert (identity.name, identity.role, identity.via) == ("alice", Role.OPERATOR, Via.TOKEN)
    assert identity.may_write
    assert users.by_token(new_token()) is None


def test_each_session_has_its_own_key_and_csrf_token_and_ends_at_logout() -> None:
    sessions = Sessions()
    key_a, a = sessions.open("alice", Role.OPERATOR)
    key_b, b = sessions.open("alice", Role.OPERATOR)
    assert key_a != key_b
    assert a.csrf_token != b.csrf_token
    assert sessions.get(key_a) is a
    sessions.close(key_a)
    assert sessions.get(key_a) is None
    assert sessions.get(key_b) is b
    assert sessions.get("a key nobody was given") is None


def test_sessions_are_bounded_the_least_recently_used_going_first() -> None:
    sessions = Sessions()
    keys = [sessions.open(f"user{n}", Role.VIEWER)[0] for n in range(MAX_SESSIONS)]
    assert sessions.get(keys[0]) is not None  # used again: now the most recent
    newest, _ = sessions.open("one more", Role.VIEWER)
    assert sessions.get(newest) is not None
    assert sessions.get(keys[0]) is not None
    assert sessions.get(keys[1]) is None  # the least recently used went


def test_failed_logins_are_free_up_to_the_limit_then_each_waits_twice_as_long() -> None:
    throttle = LoginThrottle()
    for _ in range(MAX_FAILURES - 1):
        throttle.failed("alice", "10.0.0.9")
        assert throttle.retry_after("alice", "10.0.0.9") == 0.0
    waits = []
    for _ in range(8):
        throttle.failed("alice", "10.0.0.9")
        waits.append(throttle.retry_after("alice", "10.0.0.9"))
    assert FIRST_DELAY_S * 0.9 < waits[0] <= FIRST_DELAY_S
    # 1, 2, 4, 8, 16, 32 s, then the cap.
    assert all(later > earlier * 1.8 for earlier, later in itertools.pairwise(waits[:6]))
    assert max(waits) <= MAX_DELAY_S
    assert waits[-1] > MAX_DELAY_S * 0.9  # capped, not stopped


def test_a_guesser_elsewhere_slows_only_himself_and_a_login_clears_the_count() -> None:
    throttle = LoginThrottle()
    for _ in range(MAX_FAILURES + 2):
        throttle.failed("alice", "10.0.0.9")
    assert throttle.retry_after("alice", "10.0.0.9") > 0
    assert throttle.retry_after("alice", "10.0.0.2") == 0.0  # alice at her own desk
    assert throttle.retry_after("bob", "10.0.0.9") == 0.0  # another name: its own count
    throttle.succeeded("alice", "10.0.0.9")
    assert throttle.retry_after("alice", "10.0.0.9") == 0.0


def test_many_names_tried_from_one_address_are_slowed_not_its_other_users() -> None:
    throttle = LoginThrottle()
    for n in range(MAX_ADDRESS_FAILURES + 1):
        throttle.failed(f"name{n}", "10.0.0.9")  # never more than once per name
    assert throttle.retry_after("name7", "10.0.0.9") > 0  # its second try waits
    assert throttle.retry_after("name7", "10.0.0.2") == 0.0
    # Someone else at the same shared PC (or behind the same proxy) who hasn't failed.
    assert throttle.retry_after("olga", "10.0.0.9") == 0.0


def test_only_the_first_refusal_after_a_failure_is_worth_reporting() -> None:
    throttle = LoginThrottle()
    for _ in range(MAX_FAILURES + 1):
        throttle.failed("alice", "10.0.0.9")
    assert throttle.refused("alice", "10.0.0.9") is True
    assert throttle.refused("alice", "10.0.0.9") is False
    throttle.failed("alice", "10.0.0.9")
    assert throttle.refused("alice", "10.0.0.9") is True


def test_an_anonymous_viewer_never_writes_whatever_role_it_is_given() -> None:
    assert not Identity("anonymous", Role.OPERATOR, Via.ANONYMOUS).may_write
    assert not Identity("bob", Role.VIEWER, Via.SESSION).may_write
    assert Identity("alice", Role.OPERATOR, Via.SESSION).may_write
    assert Identity("alice", Role.OPERATOR, Via.SESSION).client == "console:alice"
