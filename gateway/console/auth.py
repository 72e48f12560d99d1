"""Who is asking the console, and what they may do.

- A browser logs in with a name and password (checked against the salted scrypt hash in a
  thread, never on the event loop) and gets a session cookie: random, HttpOnly, SameSite=Strict,
  Secure under HTTPS, kept in memory (a restart logs everyone out), ended after
  `SESSION_IDLE_S` without use. Each session has its own CSRF token, which every write from
  the pages must echo in the `X-CSRF-Token` header.
- A script sends its user's API token (`Authorization: Bearer TOKEN`): no cookie, so no CSRF.
- Nobody logged in is a viewer when `anonymous_view` is on, else refused.
- Failed logins are counted per user name and client address (`LoginThrottle`): after
  `MAX_FAILURES` each further attempt from there waits twice as long as the last, so a password
  can't be guessed at the line rate, and a guesser elsewhere can't lock the operator out.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final

from gateway.passwords import token_matches, verify_password
from gateway.settings import ConsoleUser

SESSION_COOKIE: Final = "invt_console_session"
SESSION_IDLE_S: Final = 8 * 3600.0
MAX_SESSIONS: Final = 256
MAX_FAILURES: Final = 5
"""Failed logins for one name from one address at full speed; each one beyond waits longer."""
MAX_ADDRESS_FAILURES: Final = 50
"""Failed logins from one address, whatever the names, at full speed."""
FIRST_DELAY_S: Final = 1.0
MAX_DELAY_S: Final = 60.0
FORGET_S: Final = 900.0
MAX_KEYS: Final = 10_000
MAX_NAME_LENGTH: Final = 64
"""Of a name typed at the login, what is kept (throttle, events): it may be anything."""
_DUMMY_HASH: Final = "scrypt$16384$8$1$" + "A" * 22 + "$" + "A" * 43
"""Checked for an unknown user name, so its answer takes as long as a wrong password's."""


class Role(StrEnum):
    VIEWER = "viewer"
    OPERATOR = "operator"
    ADMIN = "admin"
    """What an operator may, and the configuration's editing (`gateway.console.configuration`)."""


class Via(StrEnum):
    SESSION = "session"
    TOKEN = "token"
    ANONYMOUS = "anonymous"


@dataclass(frozen=True, slots=True)
class Identity:
    name: str
    role: Role
    via: Via
    address: str | None = None
    """The client's IP address, for the audit (None: not asked over HTTP)."""

    @property
    def client(self) -> str:
        """How the bus, the traffic monitor and the audit name requests made for this user."""
        return f"console:{self.name}"

    @property
    def may_write(self) -> bool:
        return self.role in (Role.OPERATOR, Role.ADMIN) and self.via is not Via.ANONYMOUS

    @property
    def may_configure(self) -> bool:
        return self.role is Role.ADMIN and self.via is not Via.ANONYMOUS


ANONYMOUS: Final = Identity("anonymous", Role.VIEWER, Via.ANONYMOUS)


@dataclass(slots=True)
class Session:
    user: str
    role: Role
    csrf_token: str
    last_used: float


class Users:
    def __init__(self, users: Iterable[ConsoleUser]) -> None:
        self._users = {user.name: user for user in users}

    def check_password(self, name: str, password: str) -> Role | None:
        """The user's role when the password is right (slow: call it in a thread)."""
        user = self._users.get(name)
        if user is None:
            verify_password(password, _DUMMY_HASH)
            return None
        return Role(user.role) if verify_password(password, user.password_hash) else None

    def by_token(self, token: str) -> Identity | None:
        for user in self._users.values():
            if user.token_hash is not None and token_matches(token, user.token_hash):
                return Identity(user.name, Role(user.role), Via.TOKEN)
        return None

    def role_of(self, name: str) -> Role | None:
        user = self._users.get(name)
        return None if user is None else Role(user.role)


@dataclass(slots=True)
class Sessions:
    _sessions: dict[str, Session] = field(default_factory=dict)

    def open(self, user: str, role: Role) -> tuple[str, Session]:
        now = time.monotonic()
        self._expire(now)
        if len(self._sessions) >= MAX_SESSIONS:  # the oldest goes: bounded, whatever happens
            oldest = min(self._sessions, key=lambda key: self._sessions[key].last_used)
            del self._sessions[oldest]
        key = secrets.token_urlsafe(32)
        session = Session(user, role, secrets.token_urlsafe(32), now)
        self._sessions[key] = session
        return key, session

    def get(self, key: str) -> Session | None:
        session = self._sessions.get(key)
        now = time.monotonic()
        if session is None or now - session.last_used > SESSION_IDLE_S:
            self._sessions.pop(key, None)
            return None
        session.last_used = now
        return session

    def close(self, key: str) -> None:
        self._sessions.pop(key, None)

    def _expire(self, now: float) -> None:
        for key in [k for k, s in self._sessions.items() if now - s.last_used > SESSION_IDLE_S]:
            del self._sessions[key]


@dataclass(slots=True)
class _Failures:
    count: int = 0
    last: float = 0.0
    told: bool = False
    """A refusal since the last failure has been reported (the rest are only counted)."""

    def wait(self, free: int, now: float) -> float:
        """Seconds until the next attempt may be checked; 0: now."""
        beyond = self.count - free
        if beyond < 0:
            return 0.0
        delay = min(FIRST_DELAY_S * 2.0**beyond, MAX_DELAY_S)
        return max(0.0, self.last + delay - now)


@dataclass(slots=True)
class LoginCounts:
    """Login attempts by outcome, for /metrics."""

    ok: int = 0
    failed: int = 0
    throttled: int = 0
    """Refused (429) before the password was checked: its name and address must wait."""


class LoginThrottle:
    """Failed logins per (name, address), and per address over every name; beyond their free
    failures each attempt waits twice as long as the one before (up to `MAX_DELAY_S`).

    Per name *and* address, so that somebody guessing alice's password from one machine slows
    only himself: alice logs in from her own. The address's count, with more room, holds back
    only the names that have failed from there themselves: trying many names from one machine
    is slowed (each name's second try waits), while a user behind the same address (a shared
    PC, a proxy) who has not failed logs in at once, whatever a stranger there did to other
    names. A key with no failure for `FORGET_S` starts afresh; a login clears its (name,
    address). At most `MAX_KEYS` keys are kept, the longest quiet ones forgotten first."""

    def __init__(self) -> None:
        self._failures: dict[tuple[str | None, str], _Failures] = {}

    def retry_after(self, name: str, address: str) -> float:
        """Seconds until an attempt for `name` from `address` is checked; 0 when it is now."""
        now = time.monotonic()
        waits = [f.wait(free, now) for f, free in self._known(name, address, now)]
        return max(waits, default=0.0)

    def refused(self, name: str, address: str) -> bool:
        """A throttled attempt: True for the first since the last failure (worth reporting)."""
        first = False
        for failures, _ in self._known(name, address, time.monotonic()):
            first = first or not failures.told
            failures.told = True
        return first

    def failed(self, name: str, address: str) -> None:
        now = time.monotonic()
        for key in _keys(name, address):
            failures = self._failures.get(key)
            if failures is None or now - failures.last > FORGET_S:
                failures = self._failures[key] = _Failures()
            failures.count += 1
            failures.last = now
            failures.told = False
        if len(self._failures) > MAX_KEYS:
            self._forget(now)

    def succeeded(self, name: str, address: str) -> None:
        self._failures.pop(_keys(name, address)[0], None)

    def _known(self, name: str, address: str, now: float) -> list[tuple[_Failures, int]]:
        """The recent failures of (name, address) and, when there are any, of address, with
        their free counts; none for a name that has not failed from `address`."""
        found: list[tuple[_Failures, int]] = []
        frees = (MAX_FAILURES, MAX_ADDRESS_FAILURES)
        for key, free in zip(_keys(name, address), frees, strict=True):
            failures = self._failures.get(key)
            if failures is None or now - failures.last > FORGET_S:
                break  # the name's own first: without them, the address's don't apply
            found.append((failures, free))
        return found

    def _forget(self, now: float) -> None:
        """Bounded: the keys with nothing recent go, then the quietest down to 90 %."""
        for key in [k for k, f in self._failures.items() if now - f.last > FORGET_S]:
            del self._failures[key]
        excess = len(self._failures) - MAX_KEYS * 9 // 10
        if excess > 0:
            quietest = sorted(self._failures, key=lambda k: self._failures[k].last)[:excess]
            for key in quietest:
                del self._failures[key]


def _keys(name: str, address: str) -> tuple[tuple[str | None, str], tuple[str | None, str]]:
    """(name, address) and the address's own; a name as long as any worth keeping."""
    return (name[:MAX_NAME_LENGTH], address), (None, address)
