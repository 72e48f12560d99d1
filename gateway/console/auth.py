"""Who is asking the console, and what they may do.

- A browser logs in with a name and password (checked against the salted scrypt hash in a
  thread, never on the event loop) and gets a session cookie: random, HttpOnly, SameSite=Strict,
  Secure under HTTPS, kept in memory (a restart logs everyone out), ended after
  `SESSION_IDLE_S` without use. Each session has its own CSRF token, which every write from
  the pages must echo in the `X-CSRF-Token` header.
- A script sends its user's API token (`Authorization: Bearer TOKEN`): no cookie, so no CSRF.
- Nobody logged in is a viewer when `anonymous_view` is on, else refused.
- Failed logins are counted per client address and per user name: after `MAX_FAILURES` within
  `FAILURE_WINDOW_S`, further attempts are refused (429) until the window has passed, so a
  password can't be guessed at the line rate.
"""

from __future__ import annotations

import secrets
import time
from collections import deque
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
FAILURE_WINDOW_S: Final = 60.0
_DUMMY_HASH: Final = "scrypt$16384$8$1$" + "A" * 22 + "$" + "A" * 43
"""Checked for an unknown user name, so its answer takes as long as a wrong password's."""


class Role(StrEnum):
    VIEWER = "viewer"
    OPERATOR = "operator"


class Via(StrEnum):
    SESSION = "session"
    TOKEN = "token"
    ANONYMOUS = "anonymous"


@dataclass(frozen=True, slots=True)
class Identity:
    name: str
    role: Role
    via: Via

    @property
    def client(self) -> str:
        """How the bus, the traffic monitor and the audit name requests made for this user."""
        return f"console:{self.name}"

    @property
    def may_write(self) -> bool:
        return self.role is Role.OPERATOR and self.via is not Via.ANONYMOUS


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


class LoginLimiter:
    """Failed logins per key (client address, user name) in a sliding window."""

    def __init__(self) -> None:
        self._failures: dict[str, deque[float]] = {}

    def retry_after(self, keys: Iterable[str]) -> float:
        """Seconds until another attempt is allowed for every key; 0 when it is now."""
        now = time.monotonic()
        wait = 0.0
        for key in keys:
            failures = self._recent(key, now)
            if len(failures) >= MAX_FAILURES:
                wait = max(wait, failures[0] + FAILURE_WINDOW_S - now)
        return wait

    def failed(self, keys: Iterable[str]) -> None:
        now = time.monotonic()
        for key in keys:
            self._recent(key, now).append(now)
        if len(self._failures) > 10_000:  # bounded: forget the keys with nothing recent
            for key in [k for k, v in self._failures.items() if not self._recent(k, now)]:
                del self._failures[key]

    def succeeded(self, keys: Iterable[str]) -> None:
        for key in keys:
            self._failures.pop(key, None)

    def _recent(self, key: str, now: float) -> deque[float]:
        failures = self._failures.setdefault(key, deque(maxlen=MAX_FAILURES))
        while failures and now - failures[0] > FAILURE_WINDOW_S:
            failures.popleft()
        return failures
