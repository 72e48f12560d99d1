"""Who may log in to the OPC UA server, and what each may do: the console's users and roles.

    viewer              browse, read, subscribe
    operator, admin     also write and call methods (when `opcua.commands_enabled`)
    anonymous           as a viewer, only with `opcua.anonymous: true`

A login is the console's name and password, checked against its scrypt hash. A viewer's Call
request is refused whole with BadUserAccessDenied (asyncua checks each request's type, by the
`Permissions` below); a viewer's write is refused per node, with the same status, where the
write is carried out (`gateway.opcua.command_path`).
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import secrets
import time
from collections.abc import Sequence
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any, Final

from asyncua import ua
from asyncua.crypto.permission_rules import USER_TYPES, PermissionRuleset, User, UserRole

from gateway.passwords import verify_password
from gateway.settings import ConsoleUser

log = logging.getLogger(__name__)

MAY_COMMAND: Final = frozenset({"operator", "admin"})
CALL: Final = ua.NodeId(ua.ObjectIds.CallRequest_Encoding_DefaultBinary)
ALLOWED: Final = frozenset(ua.NodeId(kind) for kind in USER_TYPES)
"""The requests of a logged-in session (asyncua's list: no node management)."""
CALLER: ContextVar[Login | None] = ContextVar("opcua_caller", default=None)
"""Who made the Call request being carried out: asyncua hands a method the object and the
arguments only, and checks the request (`Permissions`) in the task that then runs it."""


@dataclass
class Login(User):  # type: ignore[misc]  # asyncua read as untyped (pyproject)
    """A session's user: asyncua's `User` (its role: a user, never asyncua's admin, who may
    add and delete nodes) with the console's role."""

    console_role: str = "viewer"
    since: float = field(default_factory=time.time)
    """When it logged in (the session's activation): the console's diagnostics show it."""

    @property
    def may_command(self) -> bool:
        return self.console_role in MAY_COMMAND

    @property
    def shown(self) -> str:
        return self.name or "anonymous"


class ConsoleLogins:
    """asyncua's user manager over the console's users."""

    def __init__(self, users: Sequence[ConsoleUser], anonymous: bool) -> None:
        self.users = {user.name: user for user in users}
        self.anonymous = anonymous
        self._key = secrets.token_bytes(32)
        self._checked: set[tuple[str, bytes]] = set()
        """(name, keyed digest of the password) of the logins that passed: scrypt takes 40 ms
        on the event loop (asyncua asks synchronously), so once per user and password."""

    def get_user(
        self,
        iserver: Any,
        username: str | None = None,
        password: str | None = None,
        certificate: Any = None,
    ) -> User | None:
        if username is None:
            return Login(role=UserRole.User, name=None) if self.anonymous else None
        user = self.users.get(username)
        if user is None or password is None or not self._password_matches(user, password):
            log.warning("OPC UA: login refused for %r", username)
            return None
        return Login(role=UserRole.User, name=username, console_role=user.role)

    def _password_matches(self, user: ConsoleUser, password: str) -> bool:
        digest = hmac.new(self._key, password.encode(), hashlib.sha256).digest()
        if (user.name, digest) in self._checked:
            return True
        if not verify_password(password, user.password_hash):
            return False
        self._checked.add((user.name, digest))
        return True


class Permissions(PermissionRuleset):  # type: ignore[misc]  # asyncua read as untyped
    """Each request's type checked against the session's user (asyncua asks before it runs)."""

    def check_validity(self, user: User, action_type_id: ua.NodeId, body: Any) -> bool:
        if action_type_id not in ALLOWED:
            return False
        if action_type_id == CALL:
            if not isinstance(user, Login) or not user.may_command:
                return False
            CALLER.set(user)
        return True
